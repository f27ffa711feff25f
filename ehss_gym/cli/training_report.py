"""``ehss training-report``: the training report of finished runs (:mod:`ehss_gym.reporting.training`).

    ehss training-report --runs runs/res_v_n2 runs/final_ppo --out reports/training --episodes 48 --ship ehss_gym/models

Evaluates every finished run under the ``--runs`` folders with the evaluation harness and writes TRAINING.md,
learning_curves.png, episodes.csv and results.json; ``--ship`` also copies the chosen residual policies' safe
weights to a models folder. Bad input (a missing folder, no finished runs) prints a message and exits with 2.
"""

from __future__ import annotations

import os
import sys

from ehss_gym.reporting import training

from .args import int_at_least

DEFAULT_OUT = os.path.join("reports", "training")


def register(sub) -> None:
    """Add ``ehss training-report`` to the sub-command parsers ``sub``."""
    p = sub.add_parser("training-report", help="evaluate finished training runs and write reports/training",
                       description="Training cost, learning curves and held-out results of the runs that ehss train "
                                   "wrote; optionally ship the chosen residual policies.")
    p.add_argument("--runs", nargs="+", default=[os.path.join("runs", "final")], metavar="FOLDER",
                   help="folders of run folders (default runs/final)")
    p.add_argument("--out", default=DEFAULT_OUT, help=f"output folder (default {DEFAULT_OUT})")
    p.add_argument("--episodes", type=int_at_least("--episodes", 1), default=48,
                   help="held-out episodes per task (default 48)")
    p.add_argument("--noise", default=os.path.join(DEFAULT_OUT, "noise_study.json"),
                   help="the noise study's JSON (python -m ehss_gym.train.noise_study); left out if missing")
    p.add_argument("--ship", default=None, metavar="FOLDER",
                   help="copy the chosen residual policies' safe weights here (e.g. ehss_gym/models)")
    p.add_argument("--workers", type=int_at_least("--workers", 1), default=2, help="evaluation processes (default 2)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


def run(args) -> int:
    """Write the report; exit code 2 with a message on bad input."""
    try:
        out = training.make_report(args.runs, args.out, episodes=args.episodes, noise=args.noise, ship=args.ship,
                                   workers=args.workers, progress=not args.no_progress)
    except ValueError as exc:  # a missing --runs folder, mixed settings in a group, no finished runs
        print(f"ehss training-report: error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {', '.join(out['files'])}" + (f"; shipped {len(out['shipped'])} models to {args.ship}"
                                                  if out["shipped"] else ""))
    return 0


__all__ = ["register", "run"]
