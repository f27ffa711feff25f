"""``ehss factors``: the ruler's factor table (:mod:`ehss_gym.study.factors`), written by
:mod:`ehss_gym.reporting.factors`; with ``--learned``, where the learned policies' figures come from
(:mod:`ehss_gym.study.factors_learned`, written by :mod:`ehss_gym.reporting.factors_learned`). Its options:
:func:`ehss_gym.cli.options.add_factors`."""

from __future__ import annotations

import sys
import time

from ehss_gym.infra.execution import Backend, Executor
from ehss_gym.infra.util import report_folder
from ehss_gym.reporting.factors import DEFAULT_OUT, write_report
from ehss_gym.reporting.factors_learned import write_learned_report
from ehss_gym.study import factors_learned
from ehss_gym.study.factors import PROG, rankings
from ehss_gym.study.factors import run as measure


def run(args) -> int:
    """Measure and write the report; print where and whether each class sees its cause, and which rankings the
    physical floors change (``--learned``: each learned group's G and which cause explains it)."""
    if args.learned:
        return run_learned(args)
    episodes = args.episodes or (6 if args.quick else 48)
    cmd = " ".join([PROG] + [a for a in getattr(args, "argv", [])[1:]])
    t0 = time.perf_counter()
    res = measure(tuple(args.task), episodes)
    with Executor(Backend("local", workers=args.workers), progress=not args.no_progress) as executor:
        ranks = rankings(tuple(args.task), episodes, executor, quick=args.quick)
    path = write_report(res, report_folder(args.out, args.quick, DEFAULT_OUT), cmd, time.perf_counter() - t0, ranks)
    for t in res:
        checks = ", ".join(f"{c['factor']}: {c['class']} x{c['ratio']:.3g} ({'met' if c['met'] else 'NOT met'})"
                           for c in t["checks"])
        print(f"{t['task']}: {checks}; start-up share of e^2 {t['startup_share']:.3f}", file=sys.stderr)
    for r in ranks:
        print(f"{r['suite']} / {r['task']}: order changed by the physical floors in "
              f"{', '.join(r['changed']) or 'no figure'}", file=sys.stderr)
    print(f"wrote {path}")
    return 0


def run_learned(args) -> int:
    """``ehss factors --learned``: measure, write LEARNED.md, print each learned group's verdict."""
    episodes = args.episodes or (2 if args.quick else 16)
    cmd = " ".join([PROG] + [a for a in getattr(args, "argv", [])[1:]])
    t0 = time.perf_counter()
    with Executor(Backend("local", workers=args.workers), progress=not args.no_progress) as executor:
        res = factors_learned.run(tuple(args.task), episodes, executor)
    path = write_learned_report(res, report_folder(args.out, args.quick, DEFAULT_OUT), cmd,
                                time.perf_counter() - t0)
    for b in res["blocks"]:
        for name, v in b["verdicts"].items():
            g = b["variants"]["as is"][name]["G"]
            print(f"{b['suite']} / {b['task']} / {name}: G {g:.3f}, {v['gap']}; explained by "
                  f"{', '.join(v['explained']) or 'no single cause'}", file=sys.stderr)
    print(f"wrote {path}")
    return 0


__all__ = ["run", "run_learned"]
