"""``ehss training-report``: the training report of finished runs (:mod:`ehss_gym.reporting.training`).

    ehss training-report --runs runs/res_v_n2 runs/final_ppo --out reports/training --episodes 48 --ship ehss_gym/models

Evaluates every finished run under the ``--runs`` folders with the evaluation harness and writes TRAINING.md,
learning_curves.png, episodes.csv and results.json; ``--ship`` also copies the chosen residual policies' safe
weights to a models folder. Bad input (a missing folder, no finished runs) prints a message and exits with 2.
"""

from __future__ import annotations

import sys

from ehss_gym.reporting import training


def run(args) -> int:
    """Write the report; exit code 2 with a message on bad input."""
    try:
        out = training.make_report(args.runs, args.out, episodes=args.episodes, noise=args.exploration, ship=args.ship,
                                   workers=args.workers, progress=not args.no_progress)
    except ValueError as exc:  # a missing --runs folder, mixed settings in a group, no finished runs
        print(f"ehss training-report: error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {', '.join(out['files'])}" + (f"; shipped {len(out['shipped'])} models to {args.ship}"
                                                  if out["shipped"] else ""))
    return 0


__all__ = ["run"]
