"""What reproduces on another CPU (docs/REPRODUCIBILITY.md, README.md), checked on held-out episodes in a child
process on an AVX2 machine's code paths (``tests/cpu_paths.py``): the ranks are the same, and the overall and class
figures of today's laws agree within 1 %, while raw per-episode metrics may move more.

The default test limits numpy, OpenBLAS, MKL and torch to AVX2 and leaves numba's machine code as it is (measured
to change nothing, bitwise, while its own cache would cost a cold compile of the kernels: about 50 CPU-seconds); the
``slow`` test adds numba's AVX2 target. On a CPU without AVX-512 the child takes the native paths and the comparison
is exact.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import pytest
from cpu_paths import MKL_AVX2, NUMPY_AVX2, OPENBLAS_AVX2, TORCH_AVX2, numba_avx2

FIGURES = ("figure", "tracking", "disturbance", "effort", "chatter")
FIGURE_RTOL = 1e-2  # the promise: two significant digits (measured on these episodes: 6.6e-4 at most)
RUN = """
import hashlib, json
import numpy as np
from ehss_gym import evaluation as ev
FIGURES = FIGURES_HERE
cfg = ev.EvalConfig(suites=("heldout",), heldout_episodes=4, n_boot=100)
res = ev.evaluate([ev.parse_policy(p) for p in ("clf-n2", "dob-n2", "pid")], cfg, workers=1, progress=False)
a = np.random.default_rng(0).standard_normal((64, 64))
print(json.dumps({
    "summary": {f"{d['task']}/{d['policy']}": [d["rank"]] + [d[k] for k in FIGURES] for d in res.summary},
    "rows": [[r["task"], r["policy"], r["episode"], repr(r["rmse"]), repr(r["dst_peak"]), repr(r["tv_u_rate"])]
             for r in res.rows],
    "blas": hashlib.sha256((a @ a).tobytes()).hexdigest()}))
""".replace("FIGURES_HERE", repr(FIGURES))


def _child(env: dict) -> dict:
    r = subprocess.run([sys.executable, "-c", RUN], capture_output=True, text=True, timeout=900,
                       env={**os.environ, **env})
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


def _check(native: dict, other: dict) -> None:
    assert native["summary"].keys() == other["summary"].keys()
    for block, (rank, *figures) in native["summary"].items():
        other_rank, *other_figures = other["summary"][block]
        assert other_rank == rank, block
        for name, a, b in zip(FIGURES, figures, other_figures):
            assert math.isfinite(a) and abs(b - a) <= FIGURE_RTOL * abs(a), (block, name, a, b)
    if other["blas"] != native["blas"]:  # the child took another path: the episodes saw it (else the check is void)
        assert other["rows"] != native["rows"]


@pytest.mark.parametrize("paths", [
    pytest.param("libraries", id="numpy-openblas-mkl-torch-avx2"),
    pytest.param("all", id="avx2-with-numba-target", marks=pytest.mark.slow),
])
def test_todays_figures_and_ranks_agree_within_one_percent_on_an_avx2_cpu(paths, tmp_path):
    env = {**NUMPY_AVX2, **OPENBLAS_AVX2, **MKL_AVX2, **TORCH_AVX2}
    if paths == "all":
        env.update(numba_avx2(str(tmp_path / "numba-avx2")))
    _check(_child({}), _child(env))
