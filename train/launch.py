"""``ehss train``: one training run, or several seeds side by side, one process per seed.

    ehss train --agent {residual-ppo,ppo} --task velocity --n 2 --timesteps T --seed S [--out runs/NAME] [--resume]
    ehss train --seeds 0-4 [--jobs J] [...]   # one process per usable core; runs go to <out or runs>/<run name>

Each seed runs ``python -m ehss_gym.train.loop`` with the seed's :class:`~ehss_gym.train.config.Config` as
flags (:func:`ehss_gym.train.options.to_argv`) and its output in ``<run>/train.log``. Every seed's settings
are validated, and its folder checked against ``--resume``, before any process starts.
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
import time

from tqdm.auto import tqdm

from . import options, runs
from .config import Config, Launch, config_from_args, launch_from_args
from .loop import describe, train

# one thread per library in each child: the seeds share the cores
CHILD_THREADS = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}


def usable_cores() -> int:
    """CPU cores this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def child_argv(cfg: Config) -> list[str]:
    """The command line of one seed's training process."""
    return [sys.executable, "-m", "ehss_gym.train.loop", *options.to_argv(dataclasses.replace(cfg, progress=False))]


def plan_seeds(args, seeds: list[int], parent: str) -> list[tuple[int, Config]]:
    """(seed, Config with its run folder) of every seed, validated and checked against ``--resume``."""
    plans = []
    for s in seeds:
        cfg = config_from_args(args, seed=s, out="")
        cfg = dataclasses.replace(cfg, out=os.path.join(parent, cfg.run_name()))
        man = runs.latest_checkpoint(cfg.out)
        if cfg.resume and man is None:
            raise runs.RunError(f"--resume: no checkpoint in {cfg.out} for seed {s}; run without --resume to start")
        if not cfg.resume and man is not None:
            raise runs.RunError(f"{cfg.out} already holds a checkpoint (step {man['step']}); pass --resume to "
                                "continue")
        plans.append((s, cfg))
    return plans


def run_seeds(plans: list[tuple[int, Config]], jobs: int, progress: bool = True) -> list[int]:
    """Train every planned seed in its own process, at most ``jobs`` at a time; the seeds that failed."""
    env = {**os.environ, **CHILD_THREADS}
    pending = list(plans)
    running: list[tuple[int, str, subprocess.Popen, float]] = []
    failed = []
    bar = tqdm(total=len(plans), desc="seeds", unit="run", disable=not progress)
    try:
        while pending or running:
            while pending and len(running) < jobs:
                s, cfg = pending.pop(0)
                os.makedirs(cfg.out, exist_ok=True)
                with open(os.path.join(cfg.out, "train.log"), "a") as log:
                    proc = subprocess.Popen(child_argv(cfg), stdout=log, stderr=subprocess.STDOUT, env=env)
                running.append((s, cfg.out, proc, time.perf_counter()))
            time.sleep(0.5)
            for item in list(running):
                s, out, proc, t0 = item
                rc = proc.poll()
                if rc is None:
                    continue
                running.remove(item)
                bar.update(1)
                bar.write(f"seed {s}: exit {rc} after {time.perf_counter() - t0:.0f} s -> {out}")
                if rc != 0:
                    failed.append(s)
    finally:
        for _, _, proc, _ in running:  # only our own children, by their handles
            proc.kill()
        bar.close()
    return failed


def run_from_args(args, prog: str = "ehss train") -> int:
    """``ehss train``: one run (``--seed``) or several (``--seeds``); bad input returns 2 with a message."""
    try:
        launch: Launch = launch_from_args(args)
        if launch.seeds is None:
            summary = train(config_from_args(args))
            print(describe(summary))
            return 0
        if args.seed is not None:
            raise runs.RunError("give either --seed or --seeds, not both")
        seeds = runs.parse_seeds(launch.seeds)
        plans = plan_seeds(args, seeds, args.out or "runs")
    except runs.RunError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    jobs = launch.jobs or usable_cores()
    print(f"training {len(seeds)} seeds {seeds} with {jobs} parallel process(es); logs in <run>/train.log")
    failed = run_seeds(plans, jobs, progress=args.progress is not False)
    if failed:
        print(f"{prog}: seeds {failed} failed; see their train.log", file=sys.stderr)
        return 1
    return 0


__all__ = ["usable_cores", "child_argv", "plan_seeds", "run_seeds", "run_from_args"]
