"""Compile numba's kernels into the session's cache before the test workers start (``tests/conftest.py``).

``python tests/warm_kernels.py sim|env``: the simulator's kernels (``simulate``, ``simulate_batch``) and the physical
bound's (about 44 CPU-seconds cold), or the env's (the vector env through an evaluation; about 47), two sets that
share almost nothing and so compile side by side in two processes. With a warm cache each takes the time to load
it (a few seconds). Without this, every xdist worker, every worker process of an ``ehss evaluate`` under test and
every Ray worker compiled the kernels it met first, each on its own.
"""

from __future__ import annotations

import sys


def warm(part: str) -> None:
    if part == "sim":
        from ehss_gym import simulate, simulate_batch
        from ehss_gym.envs import EnvConfig
        from ehss_gym.study.bound import step_bound

        for task in ("velocity", "position"):
            sc = EnvConfig.from_kwargs({"task": task}).template().replace(t_end=0.01)
            simulate(sc)
            simulate_batch([sc, sc])
        step_bound("velocity", 0.2, t_step=0.01, t_end=0.1, starts=("zero",), max_iter=1)  # a tiny one
    elif part == "env":
        from ehss_gym import evaluation as ev

        cfg = ev.EvalConfig(suites=("heldout", "step"), heldout_episodes=1, episode_seconds=0.05,
                            step_amplitudes=(0.5,), n_boot=100)
        ev.evaluate([ev.parse_policy("clf-n2"), ev.parse_policy("pid")], cfg, workers=1, progress=False)
    else:
        raise SystemExit(f"usage: python {sys.argv[0]} sim|env")


if __name__ == "__main__":
    warm(sys.argv[1])
