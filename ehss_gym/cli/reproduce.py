"""``ehss reproduce``: the paper's study regenerated, its claims tested, and where n matters.

The paper (Mintsa et al.) compares Sontag/CLF controllers with V = s^n / n for n = 2, 4, 6 but leaves out
its control period, integration, current limit, the scale of V and how its continuous filters run
digitally (NOTES items 11, 13, 14, 15). The study (:mod:`ehss_gym.study`) runs the paper's nine runs under
several stated settings, evaluates its findings C1-C7 with explicit, tested criteria, sweeps the unstated
settings for n = 2, 4, 6, checks the chosen law on the env's randomised and held-out scenarios, and
recommends the Gymnasium env's defaults with the rules that picked them; :mod:`ehss_gym.reporting.paper`
writes ``REPORT.md``, its figures, CSV tables and ``recommended_defaults.json``.
"""

from __future__ import annotations

import os
import sys
import time

from ehss_gym.infra.execution import ExecutionError, Executor, add_backend_arguments, backend_from_args, store_from_args
from ehss_gym.infra.util import report_folder
from ehss_gym.reporting.paper import write_report
from ehss_gym.study.config import StudyConfig
from ehss_gym.study.stages import run_study


def main_reproduce(out: str, quick: bool = False, progress: bool = True, cmd: str | None = None,
                   executor: Executor | None = None) -> str:
    """Run the study (its simulation batches on ``executor``, default in this process) and write the report;
    returns REPORT.md's path."""
    t0 = time.perf_counter()
    cfg = StudyConfig.quick_config() if quick else StudyConfig.full()
    cmd = cmd or ("ehss reproduce" + (" --quick" if quick else "") + f" --out {out}")
    st = run_study(cfg, progress=progress, executor=executor)
    return write_report(st, out, cmd, t_start=t0)


SHIPPED = os.path.join("reports", "paper")


def cmd_reproduce(args) -> int:
    out = report_folder(args.out, args.quick, SHIPPED)
    if not out or not str(out).strip():
        print("ehss reproduce: error: --out must be a non-empty folder path", file=sys.stderr)
        return 2
    if os.path.exists(out) and not os.path.isdir(out):
        print(f"ehss reproduce: error: --out must be a folder, {out!r} is a file", file=sys.stderr)
        return 2
    try:
        with Executor(backend_from_args(args), store_from_args(args)) as executor:
            path = main_reproduce(out, quick=args.quick, progress=not args.no_progress, executor=executor)
    except ExecutionError as exc:
        print(f"ehss reproduce: error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {path} ({executor.computed} simulation batch(es) computed, {executor.skipped} from the store)")
    return 0


def register(sub):
    p = sub.add_parser("reproduce", help="regenerate the paper's study (Figs. 5-13, claims C1-C7, sweeps, "
                                         "lost-track checks, smoothing, recommended defaults) into a report folder")
    p.add_argument("--out", default=None, help="output folder (default reports/paper; with --quick runs/quick/paper, "
                                               "so a quick run never overwrites the shipped report)")
    p.add_argument("--quick", action="store_true",
                   help="tiny grids and durations (CI smoke run; numbers not meaningful)")
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    add_backend_arguments(p)
    p.set_defaults(func=cmd_reproduce)
