"""``ehss baselines``: every scripted baseline tuned by the one coded search (:mod:`ehss_gym.study.baselines`),
written by :mod:`ehss_gym.reporting.baselines`. Its options: :func:`ehss_gym.cli.options.add_baselines`."""

from __future__ import annotations

import sys
import time

from tqdm import tqdm

from ehss_gym.infra.util import report_folder
from ehss_gym.reporting.baselines import DEFAULT_OUT, write_report
from ehss_gym.study.baselines import BASELINES, PROG, TuneSettings, tune


def settings(args) -> TuneSettings:
    """The search's settings from the options (--quick's smaller form, then any option given)."""
    base = TuneSettings.quick() if args.quick else TuneSettings()
    return TuneSettings(budget=args.budget or base.budget, episodes=args.episodes or base.episodes,
                        seconds=args.seconds or base.seconds)


def run(args) -> int:
    """Tune, write the report and print each task's default n by the rule."""
    cfg = settings(args)
    cmd = " ".join([PROG] + [a for a in getattr(args, "argv", [])[1:]])
    t0 = time.perf_counter()
    with tqdm(total=cfg.budget * len(BASELINES), desc=PROG, disable=args.no_progress) as bar:
        res = tune(cfg, progress=bar.update)
    path = write_report(res, report_folder(args.out, args.quick, DEFAULT_OUT), cmd, time.perf_counter() - t0)
    for task, d in res["defaults"].items():
        objs = ", ".join(f"n = {n}: {g:.4g}" for n, g in d["objectives"].items())
        print(f"{task}: default n = {d['n']} ({objs})", file=sys.stderr)
    print(f"wrote {path}")
    return 0


__all__ = ["run", "settings"]
