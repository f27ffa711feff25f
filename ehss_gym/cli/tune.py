"""``ehss tune``: hyperparameter search for the residual agent (Ray Tune + Optuna TPE + ASHA on the held-out
validation figure); a results table and the best config as JSON that ``ehss train --config`` reads.

    ehss tune [--task velocity --n 2] [--trials 16 --timesteps 100000 --eval-freq 25000 --grace 25000]
              [--compare-seeds 3] [--out runs/tune] [--report DIR] [--address HOST:PORT]

Runs on Ray (the ``ray`` extra: ``pip install 'ehss-gym[ray]'``): the cluster at ``--address`` or
``RAY_ADDRESS``, else a local instance with ``--cpus`` CPUs. The same command after an interruption resumes the
search (:mod:`ehss_gym.train.tune`). Exit codes: 0 done, 2 bad input (a setting, Ray missing, an unreachable
address), 1 a search in which no trial finished an evaluation.
"""

from __future__ import annotations

import os
import shlex
import sys
import time

from ehss_gym.core.execution import Backend, ExecutionError, Executor, Store
from ehss_gym.reporting.tune import write_report
from ehss_gym.train.options import parse_pairs

from .args import int_at_least


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


def cmd_tune(args) -> int:
    """Run ``ehss tune``; see the module docstring for the exit codes."""
    prog = "ehss tune"
    t0 = time.perf_counter()
    try:
        backend = Backend("ray", args.address, workers=args.cpus).validate()  # Ray missing: named here
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


def register(sub) -> None:
    """Add ``ehss tune`` to the sub-command parsers ``sub``."""
    p = sub.add_parser("tune", help="hyperparameter search for the residual agent (Ray Tune, Optuna TPE, ASHA)",
                       description="Search residual PPO's hyperparameters on the held-out validation figure with Ray "
                                   "Tune, Optuna's TPE sampler and ASHA early stopping; resumable.")
    p.add_argument("--task", choices=("velocity", "position"), default="velocity")
    p.add_argument("--n", type=int_at_least("--n", 2), default=2, help="power factor of the base law (even)")
    p.add_argument("--trials", type=int_at_least("--trials", 1), default=16, help="configurations tried")
    p.add_argument("--timesteps", type=int_at_least("--timesteps", 1), default=100_000,
                   help="agent steps of a trial ASHA does not stop (the best config's budget)")
    p.add_argument("--eval-freq", type=int_at_least("--eval-freq", 1), default=25_000,
                   help="agent steps between validation evaluations (ASHA's rungs)")
    p.add_argument("--grace", type=int_at_least("--grace", 1), default=None,
                   help="agent steps before ASHA may stop a trial (default --eval-freq)")
    p.add_argument("--eval-episodes", type=int_at_least("--eval-episodes", 1), default=8)
    p.add_argument("--eval-seconds", type=float, default=2.0, help="validation episode duration [s]")
    p.add_argument("--n-envs", type=int_at_least("--n-envs", 1), default=None, help="parallel envs per trial")
    p.add_argument("--seed", type=int_at_least("--seed", 0), default=0, help="training and sampler seed")
    p.add_argument("--concurrent", type=int_at_least("--concurrent", 1), default=2, help="trials at a time")
    p.add_argument("--compare-seeds", type=int_at_least("--compare-seeds", 0), default=0,
                   help="fresh seeds training the best config and the shipped recipe for the report's comparison")
    p.add_argument("--hp", action="append", default=None, metavar="KEY=JSON",
                   help="a hyperparameter every trial keeps (not searched), as for ehss train; repeatable")
    p.add_argument("--cpus", type=int_at_least("--cpus", 1), default=None,
                   help="CPUs of a local Ray instance (default: the usable cores)")
    p.add_argument("--address", default=None, metavar="HOST:PORT", help="the Ray cluster (default RAY_ADDRESS)")
    p.add_argument("--out", default=os.path.join("runs", "tune"),
                   help="the search's folder: Tune's state, trial runs, trials.json, best_config.json")
    p.add_argument("--report", default=None, help="folder of TUNE.md, trials.csv, compare.csv (default --out)")
    p.set_defaults(func=cmd_tune)


__all__ = ["register", "cmd_tune"]
