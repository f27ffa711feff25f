"""Two source trees side by side: this checkout against another (``--base DIR``, e.g. an export of an older commit).

    python -m benchmarks.bench_ab --base /tmp/old-checkout [--repeats 9] [--only step,batch,cli]

Every measurement runs in a fresh child process, alternating between the trees (A B A B ...), so load and drift hit
both alike; the table gives each tree's median and the ratio new / base. The child processes import the package
from the tree they measure (``PYTHONPATH``), so both use this interpreter and its libraries.

- ``step``: one single-env step (``EHSSTracking-v0``, the default settings, random actions) [us], the best of 5
  blocks of 20000 steps after a warm-up; ``vstep``: one step of the native vector env with 16 lanes [us];
- ``batch``: ``simulate_batch`` of 16 scenarios of 1 s (the env's default loop, friction) [ms], best of 10 calls;
  these three in CPU time of the child (one numba thread), which a busy machine's waits do not inflate;
- ``cli``: wall time of ``ehss --help``, of an argument error (``ehss simulate`` without ``--out``) and, as the
  peer, of ``python -c "import numpy"`` [s].

The minimum over the repeats is the least disturbed by other load; the median shows the spread. Numbers only:
nothing here asserts a speed.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

CHILD = r"""
import json, sys, time
what = sys.argv[1]
if what == "step":
    import gymnasium as gym, numpy as np
    import ehss_gym  # noqa: F401
    env = gym.make("EHSSTracking-v0").unwrapped
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    acts = [rng.uniform(-1, 1, size=1).astype(np.float32) for _ in range(1024)]
    def block(n):
        t0 = time.process_time()
        for i in range(n):
            _, _, term, trunc, _ = env.step(acts[i & 1023])
            if term or trunc:
                env.reset()
        return (time.process_time() - t0) / n
    block(2000)
    print(json.dumps(min(block(20000) for _ in range(5)) * 1e6))
elif what == "vstep":
    import numpy as np
    from ehss_gym.envs.vector import EHSSTrackingVectorEnv
    env = EHSSTrackingVectorEnv(16)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    acts = [rng.uniform(-1, 1, size=(16, 1)).astype(np.float32) for _ in range(64)]
    def block(n):
        t0 = time.process_time()
        for i in range(n):
            env.step(acts[i & 63])
        return (time.process_time() - t0) / n
    block(500)
    print(json.dumps(min(block(3000) for _ in range(5)) * 1e6))
elif what == "batch":
    from ehss_gym import simulate_batch
    from ehss_gym.envs.config import EnvConfig
    from ehss_gym.core.signals import sine
    scs = []
    for task in ("velocity", "position"):
        base = EnvConfig.from_kwargs({"task": task}).template().replace(t_end=1.0, friction=((1.8, 0.5, 0.8),))
        scs += [base.replace(reference=sine(1.0, 1.0 + i), seed=i) for i in range(8)]
    simulate_batch(scs[:2])
    best = float("inf")
    for _ in range(10):
        t0 = time.process_time()
        simulate_batch(scs)
        best = min(best, time.process_time() - t0)
    print(json.dumps(best * 1e3))
"""

CLI_CASES = {"cli_help": ["-m", "ehss_gym.cli", "--help"], "cli_error": ["-m", "ehss_gym.cli", "simulate"],
             "numpy": ["-c", "import numpy"]}
UNITS = {"step": "us", "vstep": "us", "batch": "ms", "cli_help": "s", "cli_error": "s", "numpy": "s"}


def _env(tree: str) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = tree + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env.setdefault("NUMBA_NUM_THREADS", "1")
    return env


def measure(tree: str, case: str) -> float:
    """One measurement of ``case`` with the package of ``tree`` (a fresh process)."""
    if case in CLI_CASES:
        t0 = time.perf_counter()
        subprocess.run([sys.executable, *CLI_CASES[case]], cwd=tree, env=_env(tree), capture_output=True)
        return time.perf_counter() - t0
    out = subprocess.run([sys.executable, "-c", CHILD, case], cwd=tree, env=_env(tree), capture_output=True,
                         text=True)
    if out.returncode != 0:
        raise RuntimeError(f"{case} in {tree} failed:\n{out.stderr[-2000:]}")
    return float(json.loads(out.stdout.strip().splitlines()[-1]))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.bench_ab", description=__doc__.split("\n\n")[0])
    p.add_argument("--base", required=True, help="the other source tree (a folder holding ehss_gym/)")
    p.add_argument("--repeats", type=int, default=5, help="measurements per case and tree (default 5)")
    p.add_argument("--only", default="step,vstep,batch,cli", help="comma-separated: step, vstep, batch, cli")
    args = p.parse_args(argv)
    groups = [g.strip() for g in args.only.split(",") if g.strip()]
    cases = [c for g in groups for c in (CLI_CASES if g == "cli" else [g])]
    trees = {"new": HERE, "base": os.path.abspath(args.base)}
    for tree in trees.values():  # compile (numba's cache) before timing
        for c in cases:
            if c not in CLI_CASES:
                measure(tree, c)
    times: dict = {(t, c): [] for t in trees for c in cases}
    for _ in range(args.repeats):
        for c in cases:
            for t, path in trees.items():
                times[t, c].append(measure(path, c))
    print(f"{'case':10s} {'unit':4s} {'new':>10s} {'base':>10s} {'new/base':>9s} {'min new':>10s} {'min base':>10s} "
          f"{'new/base':>9s}   (medians and minima of {args.repeats}; load {os.getloadavg()[0]:.1f})")
    for c in cases:
        a, b = statistics.median(times["new", c]), statistics.median(times["base", c])
        lo_a, lo_b = min(times["new", c]), min(times["base", c])
        print(f"{c:10s} {UNITS[c]:4s} {a:10.4g} {b:10.4g} {a / b:9.3f} {lo_a:10.4g} {lo_b:10.4g} {lo_a / lo_b:9.3f}")
    print(json.dumps({f"{t}/{c}": v for (t, c), v in times.items()}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
