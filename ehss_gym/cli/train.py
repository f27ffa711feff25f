"""``ehss train``: train residual PPO or pure PPO on EHSSTracking-v0 (one seed, or several in parallel).

    ehss train --agent {residual-ppo,ppo} --task velocity --n 2 --timesteps T --seed S [--out runs/NAME] [--resume]
    ehss train --seeds 0-4 [...]          # one process per usable core; runs go to <out or runs>/<run name>

The training script itself is :mod:`ehss_gym.train.loop`. Bad input (an unknown agent, a bad --seeds
range, --resume without a checkpoint, ...) prints a message naming the parameter and exits with 2.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time


def usable_cores() -> int:
    """CPU cores this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def _fail(msg: str) -> int:
    print(f"ehss train: error: {msg}", file=sys.stderr)
    return 2


def _child_argv(args, seed: int, out: str) -> list[str]:
    argv = [sys.executable, "-m", "ehss_gym.train.loop", "--agent", args.agent, "--task", args.task, "--n", str(args.n),
            "--timesteps", str(args.timesteps), "--seed", str(seed), "--eval-freq", str(args.eval_freq),
            "--eval-episodes", str(args.eval_episodes), "--eval-seconds", str(args.eval_seconds),
            "--checkpoint-freq", str(args.checkpoint_freq), "--out", out, "--no-progress"]
    if args.n_envs is not None:
        argv += ["--n-envs", str(args.n_envs)]
    for item in args.hp:
        argv += ["--hp", item]
    if args.resume:
        argv.append("--resume")
    return argv


def run_seeds(args, seeds: list[int]) -> int:
    """Train every seed in its own process, at most ``--jobs`` (default: usable cores) at a time."""
    from tqdm.auto import tqdm

    from ehss_gym.train import runs
    from ehss_gym.train.loop import config_from_args

    jobs = usable_cores() if args.jobs is None else args.jobs
    parent = args.out or "runs"
    plans = []
    for s in seeds:  # validate everything before starting anything
        cfg = config_from_args(args, seed=s, out="")
        out = os.path.join(parent, cfg.run_name())
        man = runs.latest_checkpoint(out)
        if args.resume and man is None:
            raise runs.RunError(f"--resume: no checkpoint in {out} for seed {s}; run without --resume to start")
        if not args.resume and man is not None:
            raise runs.RunError(f"{out} already holds a checkpoint (step {man['step']}); pass --resume to continue")
        plans.append((s, out))
    print(f"training {len(seeds)} seeds {seeds} with {jobs} parallel process(es); logs in <run>/train.log")
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}
    pending = list(plans)
    running: list[tuple[int, str, subprocess.Popen, float]] = []
    failed = []
    bar = tqdm(total=len(plans), desc="seeds", unit="run", disable=args.no_progress)
    try:
        while pending or running:
            while pending and len(running) < jobs:
                s, out = pending.pop(0)
                os.makedirs(out, exist_ok=True)
                log = open(os.path.join(out, "train.log"), "a")
                proc = subprocess.Popen(_child_argv(args, s, out), stdout=log, stderr=subprocess.STDOUT, env=env)
                log.close()
                running.append((s, out, proc, time.perf_counter()))
            time.sleep(0.5)
            for item in list(running):
                s, out, proc, t0 = item
                rc = proc.poll()
                if rc is None:
                    continue
                running.remove(item)
                bar.update(1)
                msg = f"seed {s}: exit {rc} after {time.perf_counter() - t0:.0f} s -> {out}"
                bar.write(msg)
                if rc != 0:
                    failed.append(s)
    finally:
        for _, _, proc, _ in running:  # only our own children, by their handles
            proc.kill()
        bar.close()
    if failed:
        print(f"ehss train: seeds {failed} failed; see their train.log", file=sys.stderr)
        return 1
    return 0


def run_from_args(args) -> int:
    """Entry point shared by ``ehss train`` and ``python -m ehss_gym.train.loop``."""
    from ehss_gym.train import runs
    from ehss_gym.train.loop import config_from_args, train

    try:
        if args.seeds is not None and args.seed is not None:
            raise runs.RunError("give either --seed or --seeds, not both")
        if args.jobs is not None:
            try:
                args.jobs = int(args.jobs)
            except ValueError:
                args.jobs = 0
            if args.jobs < 1:
                raise runs.RunError(f"--jobs must be an integer >= 1, got {args.jobs!r}")
        if args.seeds is not None:
            seeds = runs.parse_seeds(args.seeds)
            return run_seeds(args, seeds)
        cfg = config_from_args(args)
        summary = train(cfg)
    except runs.RunError as exc:
        return _fail(str(exc))
    b = summary["best_validation"]
    base = summary["base_validation"]["score"]
    print(f"{summary['run_name']}: {summary['timesteps']} steps in {summary['wall_s']:.0f} s; best at step "
          f"{summary['best_step']}: validation score {b['score']:.4f} (base law {base:.4f}; lower is better), "
          f"RMSE x{b['rel_rmse']:.3f}, friction peak x{b['rel_fric']:.3f}, control TV x{b['rel_tv']:.3f} of the "
          "base law")
    print(f"run folder: {summary['run_dir']} (best/policy.json + .safetensors: safe weights)")
    return 0


def register(sub):
    from ehss_gym.train.loop import build_parser

    p = sub.add_parser("train", help="train residual PPO or pure PPO (checkpoints, resume, held-out evaluation)")
    build_parser(p)
    p.set_defaults(func=run_from_args)


__all__ = ["register", "run_from_args", "run_seeds", "usable_cores"]
