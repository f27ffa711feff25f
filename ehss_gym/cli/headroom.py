"""``ehss headroom``: the headroom table (:mod:`ehss_gym.study.headroom`), written by
:mod:`ehss_gym.reporting.headroom`. Its options: :func:`ehss_gym.cli.options.add_headroom`."""

from __future__ import annotations

import sys
from dataclasses import replace

from ehss_gym.infra.execution import ExecutionError, Executor
from ehss_gym.reporting.headroom import DEFAULT_OUT, write_causes, write_report
from ehss_gym.study import headroom_causes
from ehss_gym.study.headroom import PROG, HeadroomConfig
from ehss_gym.study.headroom import run as measure

from .common import backend_from_args, check_out_folder, plant_note, plant_out_folder, store_from_args


def settings(args) -> HeadroomConfig:
    """The study's sizes from the options (--quick's smaller form, then any option given)."""
    base = HeadroomConfig.quick_config() if args.quick else HeadroomConfig()
    changes = {"tasks": tuple(args.task), "plant": args.plant, "law_settings": args.law_settings,
               "base": getattr(args, "base", base.base)}
    if args.episodes:
        changes["episodes"] = args.episodes
    if args.n_boot:
        changes["n_boot"] = args.n_boot
    return replace(base, **changes)


def _cause_names(text: str) -> tuple[str, ...] | None:
    """``--causes``' value: "all" (given without a value) -> None, else the comma-separated names."""
    return None if text == "all" else tuple(c.strip() for c in text.split(","))


def _print_causes(res: dict) -> None:
    for t in res["tasks"]:
        for name, vd in t["verdicts"].items():
            print(f"{t['task']} / {headroom_causes.SUITE}: {name}: {vd['gap']}, explained by "
                  f"{', '.join(vd['explained']) or 'no single cause'}", file=sys.stderr)


def _print_headroom(res: dict) -> None:
    print(res["cfg"].eval_config().rig.summary())
    for b in res["blocks"]:
        h = b["headroom"].get("overall")
        if h is not None:
            print(f"{b['task']} / {b['suite']}: best oracle overall {h['ratio']:.3g} [{h['lo']:.3g}, "
                  f"{h['hi']:.3g}] ({h['oracle']})", file=sys.stderr)


def run(args) -> int:
    """Measure, write the report and print each task's largest overall headroom (with ``--causes``: the cause split
    and each variant's verdict); 2 for a bad setting."""
    out = plant_out_folder(args.out, args.quick, DEFAULT_OUT, args.plant)
    if not check_out_folder(PROG, out):
        return 2
    cmd = " ".join([PROG] + [a for a in getattr(args, "argv", [])[1:]])
    split = getattr(args, "causes", None) is not None
    causes = _cause_names(args.causes) if split else None
    try:
        headroom_causes.versions(causes)
    except ValueError as exc:
        print(f"{PROG}: error: --causes: {exc}", file=sys.stderr)
        return 2
    plant_note(PROG, args.plant, args.law_settings)
    try:
        with Executor(backend_from_args(args, args.workers), store_from_args(args),
                      progress=not args.no_progress) as executor:
            res = (headroom_causes.run(settings(args), executor, causes=causes) if split
                   else measure(settings(args), executor))
    except ExecutionError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2
    path = (write_causes if split else write_report)(res, out, cmd)
    (_print_causes if split else _print_headroom)(res)
    print(f"wrote {path} ({res['computed']} job(s) computed, {res['skipped']} from the store, {res['wall_s']:.0f} s)")
    return 0

__all__ = ["run", "settings"]
