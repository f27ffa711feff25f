"""A learned policy's episodes are the same in another process and on another CPU.

The forward pass of a learned policy runs torch's float32 kernels, whose matrix products are MKL's on x86; MKL picks
its kernels by CPU, and an AVX-512 machine sums a layer's products in another order than an AVX2 one, so the actions
differ in their last bits and the closed loop carries the difference on (a fresh ``ehss evaluate`` on an AVX-512
machine moved the shipped position policy's held-out RMSE from 0.4838 to 0.4803). Every process that computes
results pins MKL's code path (``ehss_gym.infra.execution.BLAS_ENV``); a fresh process limited to AVX2 instructions
stands in for another machine here (on a host without AVX-512 the two paths are the same, and the test cannot tell
a pinned run from an unpinned one).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np

from ehss_gym import evaluation as ev
from ehss_gym.evaluation import EvalConfig
from ehss_gym.evaluation.loading import load_run
from ehss_gym.infra.execution import BLAS_ENV

TRAINED = "residual-ppo-position-n2-seed4"  # a shipped seed whose action net moved off zero in training
CFG = {"suites": ("heldout",), "tasks": ("position",), "heldout_episodes": 3, "episode_seconds": 0.4, "n_boot": 100}
RUN = f"""
import json
from ehss_gym import evaluation as ev
from ehss_gym.evaluation import EvalConfig
res = ev.evaluate([ev.parse_policy({TRAINED!r})], EvalConfig(**{CFG!r}), workers=1, progress=False)
print(json.dumps([[r["policy"], r["episode"], repr(r["rmse"]), repr(r["tv_u_rate"])] for r in res.rows]))
"""


def _episodes(env: dict | None = None) -> list:
    r = subprocess.run([sys.executable, "-c", RUN], capture_output=True, text=True, timeout=900, env=env)
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


def test_a_learned_policys_episodes_are_the_same_here_and_in_a_fresh_process_on_another_cpu_path():
    policy = load_run(ev.parse_policy(TRAINED).runs[0], "position", {})
    assert np.any(policy.tensors["action.weight"])  # the policy acts (a zero action net would hide any difference)
    assert all(os.environ.get(k) == v for k, v in BLAS_ENV.items())  # this process is pinned (tests/conftest.py)
    res = ev.evaluate([ev.parse_policy(TRAINED)], EvalConfig(**CFG), workers=1, progress=False)
    here = [[r["policy"], r["episode"], repr(r["rmse"]), repr(r["tv_u_rate"])] for r in res.rows]
    fresh = {k: v for k, v in os.environ.items() if k not in BLAS_ENV}  # a user's shell: nothing pinned
    assert _episodes(fresh) == here  # another process, this CPU
    assert _episodes({**fresh, "MKL_ENABLE_INSTRUCTIONS": "AVX2"}) == here  # another process, an AVX2 machine's MKL
