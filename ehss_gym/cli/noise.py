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

from ehss_gym.reporting.noise import write_noise_report
from ehss_gym.study.noise import run_noise_study
from ehss_gym.study.noise_config import NoiseStudyConfig


def main_noise(out: str, quick: bool = False, progress: bool = True, cmd: str | None = None) -> str:
    """Run the noise study and write its report; returns REPORT.md's path."""
    t0 = time.perf_counter()
    cfg = NoiseStudyConfig.quick_config() if quick else NoiseStudyConfig.full()
    cmd = cmd or ("ehss noise" + (" --quick" if quick else "") + f" --out {out}")
    st = run_noise_study(cfg, progress=progress)
    return write_noise_report(st, out, cmd, t_start=t0)


def cmd_noise(args) -> int:
    out = args.out
    if not out or not str(out).strip():
        print("ehss noise: error: --out must be a non-empty folder path", file=sys.stderr)
        return 2
    if os.path.exists(out) and not os.path.isdir(out):
        print(f"ehss noise: error: --out must be a folder, {out!r} is a file", file=sys.stderr)
        return 2
    path = main_noise(out, quick=args.quick, progress=not args.no_progress)
    print(f"wrote {path}")
    return 0


def register(sub):
    p = sub.add_parser("noise", help="the noise study: estimators, laws and start-up levers under sensor noise and "
                                     "the current bound, the rules choosing the env's default estimator and law")
    p.add_argument("--out", default="reports/noise", help="output folder (default reports/noise)")
    p.add_argument("--quick", action="store_true",
                   help="tiny grids and durations (CI smoke run; numbers not meaningful)")
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    p.set_defaults(func=cmd_noise)
