"""``ehss train``: one training run, or several seeds side by side, each seed a job of the execution layer.

    ehss train --agent {residual-ppo,ppo} --task velocity --n 2 --timesteps T --seed S [--out runs/NAME] [--resume]
    ehss train --seeds 0-4 [--workers W] [--backend ray [--address HOST:PORT]] [...]   # runs go to <out or runs>/<name>

Each seed is a :func:`~ehss_gym.train.jobs.train_job` on the chosen backend (:mod:`ehss_gym.infra.execution`):
locally, a fresh worker process per seed, at most ``--workers`` at a time; on Ray, one task per seed (retried, and
resumed from its last checkpoint, if its worker dies). Its output goes to ``<run>/train.log``. Every seed's
settings are validated, and its folder checked against ``--resume``, before any job starts; a seed whose job
result is already in the store (``<out or runs>/jobs``) is not trained again.
"""

from __future__ import annotations

import dataclasses
import os
import sys

from ehss_gym.infra.execution import Backend, ExecutionError, Executor, Store, job_key

from . import runs
from .config import Config, Launch, config_from_args, launch_from_args
from .jobs import materialize, seed_job
from .loop import describe, train


def plan_seeds(args, seeds: list[int], parent: str, store: Store | None = None) -> list[tuple[int, Config]]:
    """(seed, Config with its run folder) of every seed, validated and checked against ``--resume`` (a seed whose
    result ``store`` holds is finished: it is not checked)."""
    plans = []
    for s in seeds:
        cfg = config_from_args(args, seed=s, out="")
        cfg = dataclasses.replace(cfg, out=os.path.join(parent, cfg.run_name()))
        if store is not None and store.load(job_key(seed_job(cfg))) is not None:
            plans.append((s, cfg))
            continue
        man = runs.latest_checkpoint(cfg.out)
        if cfg.resume and man is None:
            raise runs.RunError(f"--resume: no checkpoint in {cfg.out} for seed {s}; run without --resume to start")
        if not cfg.resume and man is not None:
            raise runs.RunError(f"{cfg.out} already holds a checkpoint (step {man['step']}); pass --resume to "
                                "continue")
        plans.append((s, cfg))
    return plans


def run_seeds(plans: list[tuple[int, Config]], executor: Executor) -> list[dict]:
    """Train every planned seed on ``executor`` (a fresh process per seed locally); their job results, with the
    weights of seeds trained on another machine written into their run folders."""
    results = executor.map([seed_job(cfg) for _, cfg in plans], desc="seeds", fresh_process=True)
    for res in results:
        materialize(res)
    return results


def launch_executor(launch: Launch, parent: str, progress: bool) -> Executor:
    """The executor of a ``--seeds`` launch: its backend, and its store in ``<parent>/jobs`` (or ``--store``)."""
    backend = Backend(launch.backend, launch.address, workers=launch.workers).validate()
    store = None if launch.no_store else Store(launch.store or os.path.join(parent, "jobs"))
    return Executor(backend, store, progress=progress)


def run_from_args(args, prog: str = "ehss train") -> int:
    """``ehss train``: one run (``--seed``) or several (``--seeds``); bad input returns 2 with a message."""
    try:
        launch: Launch = launch_from_args(args)
        if launch.seeds is None:
            if launch.backend != "local" or launch.address is not None:
                raise runs.RunError("--backend and --address run the seeds of --seeds; one --seed trains here")
            summary = train(config_from_args(args))
            print(describe(summary))
            return 0
        if args.seed is not None:
            raise runs.RunError("give either --seed or --seeds, not both")
        seeds = runs.parse_seeds(launch.seeds)
        parent = args.out or "runs"
        executor = launch_executor(launch, parent, progress=args.progress is not False)
        plans = plan_seeds(args, seeds, parent, executor.store)
        with executor:
            where = f"{executor.workers()} parallel job(s) on the {launch.backend} backend"
            print(f"training {len(seeds)} seeds {seeds} with {where}; logs in <run>/train.log")
            results = run_seeds(plans, executor)
    except (runs.RunError, ExecutionError) as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except RuntimeError as exc:  # a seed's job failed; the seeds finished before it are in the store
        print(f"{prog}: error: {exc}; see its train.log", file=sys.stderr)
        return 1
    for res in results:
        print(describe(res["summary"]))
    print(f"{executor.computed} seed(s) trained, {executor.skipped} already finished (in {executor.store.root})"
          if executor.store is not None else f"{executor.computed} seed(s) trained")
    return 0


__all__ = ["plan_seeds", "run_seeds", "launch_executor", "run_from_args"]
