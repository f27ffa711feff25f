"""``ehss baselines``: every scripted baseline tuned by the one coded search (:mod:`ehss_gym.study.baselines`),
written by :mod:`ehss_gym.reporting.baselines`. Its options: :func:`ehss_gym.cli.options.add_baselines`."""

from __future__ import annotations

import os
import sys
import time
from dataclasses import replace

from tqdm import tqdm

from ehss_gym.core.rig import as_rig
from ehss_gym.reporting.baselines import DEFAULT_OUT, LAW_SETTINGS_FILE, write_report
from ehss_gym.study.baselines import BASELINES, PROG, TuneSettings, tune
from ehss_gym.study.compensators import evaluations

from .common import plant_out_folder


def settings(args) -> TuneSettings:
    """The search's settings from the options (--quick's smaller form, then any option given)."""
    base = TuneSettings.quick() if args.quick else TuneSettings()
    rows = () if set(args.task) == {r.task for r in BASELINES} else tuple(r.name for r in BASELINES
                                                                          if r.task in args.task)
    return replace(base, budget=args.budget or base.budget, episodes=args.episodes or base.episodes,
                   seconds=args.seconds or base.seconds, plant=args.plant, rows=rows,
                   check_episodes=base.check_episodes if args.check_episodes is None else args.check_episodes,
                   compensator_episodes=(base.compensator_episodes if args.compensator_episodes is None
                                         else args.compensator_episodes))


def run(args) -> int:
    """Tune, write the report and print each task's default n by the rule and the held-out check."""
    cfg = settings(args)
    cmd = " ".join([PROG] + [a for a in getattr(args, "argv", [])[1:]])
    t0 = time.perf_counter()
    rows = [r for r in BASELINES if not cfg.rows or r.name in cfg.rows]
    comps = evaluations() * len({r.task for r in rows}) if cfg.compensator_episodes else 0  # their candidates
    total = cfg.budget * len(rows) + comps
    with tqdm(total=total, desc=PROG, disable=args.no_progress) as bar:
        res = tune(cfg, progress=bar.update)
    out = plant_out_folder(args.out, args.quick, DEFAULT_OUT, args.plant)
    path = write_report(res, out, cmd, time.perf_counter() - t0)
    print(as_rig(cfg.plant).summary())
    for task, d in res["defaults"].items():
        objs = ", ".join(f"n = {n}: {g:.4g}" for n, g in d["objectives"].items())
        print(f"{task}: default n = {d['n']} ({objs})", file=sys.stderr)
    for task, d in res["check"].items():
        for which in ("tuned", "untuned"):
            c = d[which]
            print(f"{task}, {which} n = 2 law on {c['episodes']} held-out episodes: saturation {c['saturation']:.2%}, "
                  f"{c['limit_cycles']}/{c['windows']} friction windows with a limit cycle, {c['failed']} failed: "
                  f"{'pass' if c['passed'] else 'FAIL'}")
    print(f"wrote {path} and {os.path.join(out, LAW_SETTINGS_FILE)}")
    return 0


__all__ = ["run", "settings"]
