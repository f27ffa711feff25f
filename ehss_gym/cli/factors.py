"""``ehss factors``: the ruler's factor table (:mod:`ehss_gym.study.factors`), written by
:mod:`ehss_gym.reporting.factors`."""

from __future__ import annotations

import sys
import time

from ehss_gym.core.util import report_folder
from ehss_gym.reporting.factors import DEFAULT_OUT, write_report
from ehss_gym.study.factors import PROG, run

from .args import int_at_least
from .evaluate import _tasks


def register(sub) -> None:
    """Add ``factors`` to the ``ehss`` sub-commands."""
    p = sub.add_parser("factors", help="the ruler's factor table: each metric class with friction, mismatch and "
                                       "noise removed",
                       description="The default law on the held-out suite with friction, model mismatch and sensor "
                                   "noise removed one at a time and all together: each metric class's level; "
                                   "writes FACTORS.md and factors.csv.")
    p.add_argument("--episodes", type=int_at_least("--episodes", 1), default=None,
                   help="held-out episodes per task (default 48; --quick 6)")
    p.add_argument("--tasks", type=_tasks, default=("velocity", "position"),
                   help="comma-separated subset of velocity,position")
    p.add_argument("--out", default=None, help=f"output folder (default {DEFAULT_OUT}; with --quick "
                                               "runs/quick/factors)")
    p.add_argument("--quick", action="store_true", help="6 held-out episodes per task")
    p.set_defaults(func=cmd_factors)


def cmd_factors(args) -> int:
    """Measure and write the report; print where."""
    episodes = args.episodes or (6 if args.quick else 48)
    cmd = " ".join([PROG] + [a for a in getattr(args, "argv", [])[1:]])
    t0 = time.perf_counter()
    res = run(tuple(args.tasks), episodes)
    path = write_report(res, report_folder(args.out, args.quick, DEFAULT_OUT), cmd, time.perf_counter() - t0)
    for t in res:
        checks = ", ".join(f"{c['factor']}: {c['class']} x{c['ratio']:.3g} ({'met' if c['met'] else 'NOT met'})"
                           for c in t["checks"])
        print(f"{t['task']}: {checks}; start-up share of e^2 {t['startup_share']:.3f}", file=sys.stderr)
    print(f"wrote {path}")
    return 0
