"""``ehss evaluate``: the evaluation harness (:mod:`ehss_gym.evaluation`) on the command line, then its report
(:mod:`ehss_gym.reporting.comparison`)."""

from __future__ import annotations

import argparse
import os
import sys
import warnings
from dataclasses import replace

from ehss_gym.core.execution import Executor, add_backend_arguments, backend_from_args, store_from_args
from ehss_gym.core.util import report_folder
from ehss_gym.evaluation import SUITES, TASKS, EvalConfig, PolicyWarning, default_specs, evaluate, parse_policies
from ehss_gym.reporting.comparison import DEFAULT_OUT, write_report

from .args import int_at_least


def _tasks(text: str) -> tuple:
    """``--tasks``: a comma-separated subset of the tasks."""
    names = tuple(t.strip() for t in text.split(",") if t.strip())
    if not names or any(t not in TASKS for t in names):
        raise argparse.ArgumentTypeError(f"--tasks must be a comma-separated subset of {','.join(TASKS)}, got {text!r}")
    return names


def register(sub) -> None:
    """Add ``evaluate`` to the ``ehss`` sub-commands."""
    p = sub.add_parser("evaluate", help="compare CLF n=2/4/6, PID and learned policies on the same scenarios",
                       description="Measure scripted and learned policies against the reference law (clf-n2) by "
                                   "metric class (tracking, disturbance, effort, chatter) on the paper scenario, a "
                                   "held-out randomised suite, robustness sweeps and a step suite; write REPORT.md, "
                                   "CSVs and figures.")
    p.add_argument("--policies", nargs="+", default=None, metavar="SPEC",
                   help="comma- or space-separated: clf-n2, clf-n4, clf-n6, pid, residual-ppo:PATH, ppo-direct:PATH, "
                        "sb3:PATH (any SB3 algorithm, its mode from the env spec saved with it), or a shipped model "
                        "name (default: every shipped policy)")
    p.add_argument("--suite", choices=(*SUITES, "all"), default="all")
    p.add_argument("--tasks", type=_tasks, default=TASKS, help="comma-separated subset of velocity,position")
    p.add_argument("--episodes", type=int_at_least("--episodes", 1), default=None,
                   help="held-out episodes per task (default 48; --quick 8)")
    p.add_argument("--sweep-episodes", type=int_at_least("--sweep-episodes", 1), default=None,
                   help="episodes per robustness level (default 5; --quick 1)")
    p.add_argument("--workers", type=int_at_least("--workers", 1), default=None,
                   help="worker processes (default: the cores available)")
    p.add_argument("--n-boot", type=int_at_least("--n-boot", 100), default=None, help="bootstrap replicates")
    p.add_argument("--seed", type=int_at_least("--seed", 0), default=0, help="bootstrap seed")
    p.add_argument("--out", default=None,
                   help=f"output folder (default {DEFAULT_OUT}; with --quick runs/quick/comparison, so a quick run "
                        "never overwrites the shipped report unless --out says so)")
    p.add_argument("--quick", action="store_true",
                   help="small CI form: 8 held-out episodes, 3+2 sweep levels of 1 episode, paper run cut at 12 s, "
                        "3 steps")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_backend_arguments(p)
    p.set_defaults(func=cmd_evaluate)


def _command_line(args) -> str:
    """The command line as the report records it (the real one when run as ``ehss evaluate``)."""
    if sys.argv and os.path.basename(sys.argv[0]) == "ehss" and len(sys.argv) > 1 and sys.argv[1] == "evaluate":
        return "ehss " + " ".join(sys.argv[1:])
    parts = ["ehss evaluate"]
    if args.policies:
        parts.append("--policies " + " ".join(args.policies))
    if args.suite != "all":
        parts.append(f"--suite {args.suite}")
    if tuple(args.tasks) != TASKS:
        parts.append("--tasks " + ",".join(args.tasks))
    for flag, v in (("--episodes", args.episodes), ("--sweep-episodes", args.sweep_episodes),
                    ("--workers", args.workers), ("--n-boot", args.n_boot)):
        if v is not None:
            parts.append(f"{flag} {v}")
    if args.seed:
        parts.append(f"--seed {args.seed}")
    if args.out is not None:
        parts.append(f"--out {args.out}")
    if args.quick:
        parts.append("--quick")
    return " ".join(parts)


def config_from_args(args) -> EvalConfig:
    """The evaluation's sizes from the options (``--quick`` first, the explicit sizes on top)."""
    changes = {"suites": SUITES if args.suite == "all" else (args.suite,), "tasks": tuple(args.tasks),
               "seed": args.seed}
    for key, v in (("heldout_episodes", args.episodes), ("sweep_episodes", args.sweep_episodes),
                   ("n_boot", args.n_boot)):
        if v is not None:
            changes[key] = v
    return EvalConfig.quick(**changes) if args.quick else replace(EvalConfig(), **changes)


def cmd_evaluate(args) -> int:
    """Evaluate, write the report, print the rankings.

    Returns:
        0 on success, 2 for a policy or setting that cannot be evaluated, 1 for a policy that failed while running.
    """
    prog = "ehss evaluate"
    try:
        with warnings.catch_warnings(record=True) as caught:  # printed below as the CLI's own warnings
            warnings.simplefilter("always", PolicyWarning)
            cfg = config_from_args(args)
            specs = default_specs() if args.policies is None else parse_policies(args.policies)
            for w in caught:
                print(f"{prog}: warning: {w.message}", file=sys.stderr)
            with Executor(backend_from_args(args, args.workers), store_from_args(args),
                          progress=not args.no_progress) as executor:
                res = evaluate(specs, cfg, workers=args.workers, progress=not args.no_progress,
                               command=_command_line(args), executor=executor)
    except ValueError as exc:  # PolicyError, SafeWeightsError, ExecutionError (backend, address), bad settings
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except RuntimeError as exc:  # a policy that misbehaved while running (e.g. a NaN action)
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 1
    print(f"{prog}: {executor.computed} job(s) computed, {executor.skipped} from the store", file=sys.stderr)
    for note in res.notes:
        print(f"{prog}: note: {note}", file=sys.stderr)
    path = write_report(res, report_folder(args.out, args.quick, DEFAULT_OUT))
    print(f"{len(res.rows)} episodes in {res.wall_time:.1f} s ({res.workers} workers; "
          + ", ".join(f"{k} {v:.1f} s" for k, v in res.timings.items()) + f"); wrote {path}")
    for suite in SUITES:
        for task in TASKS:
            block = [d for d in res.summary if d["suite"] == suite and d["task"] == task]
            if block:
                ranking = ", ".join(f"{d['policy']} {d['figure']:.3g}" + (" FAILED" if d["failed"] else "")
                                    + (" (earlier loop)" if d["earlier_loop"] else "") for d in block)
                print(f"  {suite}/{task}: {ranking}")
    return 0


