"""``ehss ablation``: the residual recipe's ablation (:mod:`ehss_gym.study.ablation`) and its report
(:mod:`ehss_gym.reporting.ablation`).

    ehss ablation --runs runs/ablation --out reports/training/ablation [--workers 2] [--report-only]

Trains the cells that have not finished (one ``ehss train`` process each, at most ``--workers`` at a time; stage 2
once stage 1 has finished, stage 3 once stage 2 has), ranks them by the rule written before the runs and writes
ABLATION.md, curves.png and ablation.csv. Bad input (no finished cell to report) prints a message and exits with 2.
"""

from __future__ import annotations

import sys
import time

from ehss_gym.reporting.ablation import command_line, write_report
from ehss_gym.study.ablation import run_ablation


def run(args) -> int:
    """Train what is missing, rank, write the report; exit code 2 with a message when no cell has finished."""
    t0 = time.perf_counter()
    study = run_ablation(args.runs, args.timesteps, args.workers, train=not args.report_only,
                         progress=not args.no_progress)
    if not study.order:
        print(f"ehss ablation: error: no finished cell under {args.runs} (run without --report-only to train them)",
              file=sys.stderr)
        return 2
    files = write_report(study, args.out, command_line(args.runs, args.out, args.timesteps))
    w = study.order[0]
    print(f"winner: {w['label']} (final validation figure {w['final']:.4f}, step 0 {w['step0']:.4f}); "
          f"wrote {', '.join(files)} in {time.perf_counter() - t0:.0f} s")
    return 0


__all__ = ["run"]
