"""``ehss warmup``: compile numba's kernels into the cache now, for a Docker image or a Ray node, so the first real
run loads them instead of compiling (the note of :mod:`ehss_gym.core.compile_note`).

It compiles by running what the commands run, tiny: no list of kernels to keep in step with the code. ``sim``: a
first :func:`~ehss_gym.simulate` and :func:`~ehss_gym.simulate_batch` per task and a tiny step bound (the simulator,
``ehss simulate``, ``ehss reproduce``, the bounds of ``ehss evaluate``); ``env``: a tiny evaluation through the
vector env (the env, ``ehss evaluate``, ``ehss train``). The two share almost nothing, so the test session compiles
them side by side in two processes (``tests/warm_kernels.py``). With a warm cache each takes the time to load it.
"""

from __future__ import annotations

import time
from dataclasses import replace

from ehss_gym import evaluation as ev
from ehss_gym import simulate, simulate_batch
from ehss_gym.core.compile_note import cache_folder
from ehss_gym.core.loop import run_batch
from ehss_gym.envs import EnvConfig
from ehss_gym.study.bound import step_bound


def warm_sim() -> None:
    """The simulator's kernels and the step bound's."""
    for task in ("velocity", "position"):
        sc = EnvConfig.from_kwargs({"task": task}).template().replace(t_end=0.01)
        simulate(sc)
        simulate_batch([sc, sc])
    step_bound("velocity", 0.2, t_step=0.01, t_end=0.1, starts=("zero",), max_iter=1)  # a tiny one


def warm_env() -> None:
    """The env's kernels, through an evaluation of a scripted law, the PID and one seed of a shipped learned policy
    (its observation normalisation is compiled) on short episodes (two lanes of the vector env in the held-out suite,
    one in the step suite)."""
    cfg = ev.EvalConfig(suites=("heldout", "step"), heldout_episodes=2, episode_seconds=0.05, step_amplitudes=(0.5,),
                        n_boot=100)
    learned = [replace(s, runs=s.runs[:1]) for s in ev.shipped_specs()[:1]]
    ev.evaluate([ev.parse_policy("clf-n2"), ev.parse_policy("pid"), *learned], cfg, workers=1, progress=False)


PARTS = {"sim": warm_sim, "env": warm_env}


def run(args) -> int:
    """Warm every part (or ``--part``'s) in this process; prints the CPU time [s] each took and where the cache is."""
    parts = [args.part] if args.part else list(PARTS)
    spent = []
    for part in parts:
        cpu = time.process_time()
        PARTS[part]()
        spent.append(f"{part} {time.process_time() - cpu:.1f}")
    print(f"kernels compiled or loaded ({', '.join(spent)} CPU-seconds); cache: "
          f"{cache_folder(run_batch.stats.cache_path)}")
    return 0


__all__ = ["run", "warm_sim", "warm_env", "PARTS"]
