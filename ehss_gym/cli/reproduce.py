"""``ehss reproduce``: the paper's study regenerated, its claims tested, and where n matters.

The paper (Mintsa et al.) compares Sontag/CLF controllers with V = s^n / n for n = 2, 4, 6 but leaves out
its control period, integration, current limit, the scale of V and how its continuous filters run
digitally (docs/MODEL.md). The study (:mod:`ehss_gym.study`) runs the paper's nine runs under
several stated settings, evaluates its findings C1-C7 with explicit, tested criteria, sweeps the unstated
settings for n = 2, 4, 6, checks the chosen law on the env's randomised and held-out scenarios, and
recommends the Gymnasium env's defaults with the rules that picked them; :mod:`ehss_gym.reporting.paper`
writes ``REPORT.md``, its figures, CSV tables and ``recommended_defaults.json``.
"""

from __future__ import annotations

import os
import sys
import time

from ehss_gym.infra.execution import ExecutionError, Executor
from ehss_gym.infra.util import report_folder
from ehss_gym.reporting.paper import write_report
from ehss_gym.study.config import StudyConfig
from ehss_gym.study.stages import run_study

from .common import backend_from_args, check_out_folder, store_from_args


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


def run(args) -> int:
    """Run the study and write its report; 2 (with a message) for a bad ``--out`` or execution setting."""
    if args.plant is not None:
        print("ehss reproduce: error: --plant is not taken: the reproduction study tests the paper's claims on the "
              "paper's rig (Table I); on your plant, `ehss evaluate --plant FILE` runs the paper's scenario among its "
              "suites and compares n = 2/4/6, after `ehss baselines --plant FILE` (docs: 'Your own servo')",
              file=sys.stderr)
        return 2
    out = report_folder(args.out, args.quick, SHIPPED)
    if not check_out_folder("ehss reproduce", out):
        return 2
    try:
        with Executor(backend_from_args(args), store_from_args(args)) as executor:
            path = main_reproduce(out, quick=args.quick, progress=not args.no_progress, executor=executor)
    except ExecutionError as exc:
        print(f"ehss reproduce: error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {path} ({executor.computed} simulation batch(es) computed, {executor.skipped} from the store)")
    return 0


__all__ = ["run", "main_reproduce"]
