"""``ehss tune``: hyperparameter search for the residual agent (Ray Tune + Optuna TPE + ASHA on the held-out
validation figure); a results table and the best config as JSON that ``ehss train --config`` reads.

    ehss tune [--task velocity --n 2] [--trials 16 --timesteps 100000 --eval-freq 25000 --grace 25000]
              [--compare-seeds 3] [--out runs/tune] [--report DIR] [--address HOST:PORT]

Runs on Ray (the ``ray`` extra: ``pip install 'ehss-gym[ray]'``): the cluster at ``--address`` or
``RAY_ADDRESS``, else a local instance with ``--workers`` CPUs. The same command after an interruption resumes the
search (:mod:`ehss_gym.train.tune`). Exit codes: 0 done, 2 bad input (a setting, Ray missing, an unreachable
address), 1 a search in which no trial finished an evaluation.
"""

from __future__ import annotations

import os
import shlex
import sys
import time

from ehss_gym.infra.execution import Backend, ExecutionError, Executor, Store
from ehss_gym.reporting.tune import write_report
from ehss_gym.train.options import parse_pairs


def _settings(args):
    """The search's settings from the options (TuneSettings, from the module that needs Ray)."""
    from ehss_gym.train import tune as search  # Ray Tune and Optuna load only when ehss tune runs (the ray extra)

    cfg = search.TuneSettings(task=args.task, n=args.n, trials=args.trials, timesteps=args.timesteps,
                              eval_freq=args.eval_freq, grace=args.grace or args.eval_freq,
                              eval_episodes=args.eval_episodes, eval_seconds=args.eval_seconds, n_envs=args.n_envs,
                              seed=args.seed, concurrent=args.concurrent, compare_seeds=args.compare_seeds,
                              fixed_hp=parse_pairs("hp", args.hp), out=args.out)
    clash = sorted(set(cfg.fixed_hp) & set(search.SEARCH_SPACE))
    if clash:
        raise ExecutionError(f"--hp {', '.join(clash)}: searched by ehss tune, cannot be fixed")
    if cfg.grace > cfg.timesteps or cfg.eval_freq > cfg.timesteps:
        raise ExecutionError(f"--grace and --eval-freq must be <= --timesteps ({cfg.timesteps}), got "
                             f"{cfg.grace} and {cfg.eval_freq}")
    cfg.base_config({}, cfg.seed, cfg.out)  # the training settings' own checks (RunError names the option)
    return search, cfg


def run(args) -> int:
    """Run ``ehss tune``; see the module docstring for the exit codes."""
    prog = "ehss tune"
    t0 = time.perf_counter()
    try:
        backend = Backend("ray", args.address, workers=args.workers).validate()  # Ray missing: named here
        search, settings = _settings(args)
        # the comparison's training seeds are jobs with a store: a rerun (or a restart) does not train them again
        with Executor(backend, Store(os.path.join(args.out, "jobs"))) as executor:
            result = search.run_search(settings, executor)
    except ValueError as exc:  # ExecutionError, RunError: bad settings, Ray missing, address unreachable
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except RuntimeError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 1
    command = "ehss " + " ".join(shlex.quote(a) for a in getattr(args, "argv", ["tune"]))
    path = write_report(result, settings, args.report or args.out, command, time.perf_counter() - t0)
    best = result["trials"][0]
    print(f"{len(result['trials'])} trials; best {best['trial']}: validation objective {best['best_objective']:.4f} "
          f"after {best['steps']} steps; wrote {os.path.join(args.out, 'best_config.json')} and {path}")
    return 0


__all__ = ["run"]
