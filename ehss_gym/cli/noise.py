"""``ehss noise``: estimators, laws and start-up levers against sensor noise and the current bound.

Runs the noise study (:mod:`ehss_gym.study.noise`: the old loop's lost start-ups and the levers on them, Lin-Sontag's
sigma, the maps of noise level x estimator x law x n for both tasks, the coded rules that choose the env's default
estimator and law per task, the final check against the old defaults and the PID, where n matters at the new
defaults, and the "state" estimator's bias under mismatch) and writes its report
(:mod:`ehss_gym.reporting.noise`: ``REPORT.md``, figures, CSV tables and ``recommended.json``).
"""

from __future__ import annotations

import os
import sys
import time

from ehss_gym.infra.execution import ExecutionError, Executor
from ehss_gym.infra.util import report_folder
from ehss_gym.reporting.noise import write_noise_report
from ehss_gym.study.noise import run_noise_study
from ehss_gym.study.noise_config import NoiseStudyConfig

from .common import backend_from_args, check_out_folder, store_from_args

SHIPPED = os.path.join("reports", "noise")


def main_noise(out: str, quick: bool = False, progress: bool = True, cmd: str | None = None,
               executor: Executor | None = None) -> str:
    """Run the noise study (its simulation batches on ``executor``, default in this process) and write its report;
    returns REPORT.md's path."""
    t0 = time.perf_counter()
    cfg = NoiseStudyConfig.quick_config() if quick else NoiseStudyConfig.full()
    cmd = cmd or ("ehss noise" + (" --quick" if quick else "") + f" --out {out}")
    st = run_noise_study(cfg, progress=progress, executor=executor)
    return write_noise_report(st, out, cmd, t_start=t0)


def run(args) -> int:
    """Run the study and write its report; 2 (with a message) for a bad ``--out`` or execution setting."""
    out = report_folder(args.out, args.quick, SHIPPED)
    if not check_out_folder("ehss noise", out):
        return 2
    try:
        with Executor(backend_from_args(args), store_from_args(args)) as executor:
            path = main_noise(out, quick=args.quick, progress=not args.no_progress, executor=executor)
    except ExecutionError as exc:
        print(f"ehss noise: error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {path} ({executor.computed} simulation batch(es) computed, {executor.skipped} from the store)")
    return 0


__all__ = ["run", "main_noise"]
