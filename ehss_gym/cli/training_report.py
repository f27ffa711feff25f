"""``ehss training-report``: the training study of finished runs (:mod:`ehss_gym.study.training`) and its report
(:mod:`ehss_gym.reporting.training`).

    ehss training-report --runs runs/res_v_n2 runs/ppo_v_n2 --out reports/training --episodes 48 --ship ehss_gym/models

Evaluates every finished run under the ``--runs`` folders with the evaluation harness and writes TRAINING.md, a
learning-curve PNG per group, episodes.csv and results.json; ``--ship`` also copies the kept policies' safe weights
to a models folder and retires the models there that it does not write; ``--archive`` keeps every run's records (what
the report reads) in a folder that ``--runs`` can read again. Bad input (a missing folder, no finished
runs) prints a message and exits with 2.
"""

from __future__ import annotations

import sys

from ehss_gym.reporting.training import COMMAND, command_line, write_report
from ehss_gym.study.training import run_training_study


def run(args) -> int:
    """Run the study and write the report; exit code 2 with a message on bad input."""
    try:
        study = run_training_study(args.runs, args.episodes, exploration=args.exploration, ship_to=args.ship,
                                   workers=args.workers, progress=not args.no_progress, made_by=COMMAND,
                                   archive_to=args.archive)
    except ValueError as exc:  # a missing --runs folder, mixed settings in a group, no finished runs, a name clash
        print(f"ehss training-report: error: {exc}", file=sys.stderr)
        return 2
    files = write_report(study, args.out, command_line(args.runs, args.out, args.episodes, args.ship, args.archive))
    sh = study.shipment
    print(f"wrote {', '.join(files)}" + (f"; shipped {len(sh.written)} models to {args.ship}, retired "
                                         f"{len(sh.retired)}" if sh is not None else ""))
    return 0


__all__ = ["run"]
