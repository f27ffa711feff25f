"""The factor table's report (``ehss factors``): ``FACTORS.md`` (prose in templates/factors.md.j2) and
``factors.csv``, from :func:`ehss_gym.study.factors.run`."""

from __future__ import annotations

import os

from ehss_gym._version import __version__
from ehss_gym.core.sim import UNITS
from ehss_gym.evaluation.scoring import CLASSES
from ehss_gym.infra.fmt import fmt_cell
from ehss_gym.infra.util import atomic_write_text
from ehss_gym.study.factors import MOVE

from .comparison import csv_text
from .render import render

DEFAULT_OUT = os.path.join("reports", "factors")
COLUMNS = ("task", "factor") + CLASSES + tuple(f"{c}_ratio" for c in CLASSES)


def _rows(t: dict) -> list[list[str]]:
    """One table row per factor: each class's level and, in brackets, its ratio to the suite as it is."""
    return [[r["factor"]] + [f"{fmt_cell(r[c])} ({fmt_cell(r[f'{c}_ratio'])}x)" for c in CLASSES]
            for r in t["rows"]]


def write_report(results: list[dict], out: str, command: str, wall_s: float) -> str:
    """Write FACTORS.md and factors.csv under ``out``; returns FACTORS.md's path."""
    os.makedirs(out, exist_ok=True)
    flat = [{"task": t["task"], **r} for t in results for r in t["rows"]]
    atomic_write_text(os.path.join(out, "factors.csv"), csv_text(flat, COLUMNS))
    tasks = [{**t, "unit": UNITS[t["task"]], "table": _rows(t)} for t in results]
    text = render("factors.md.j2", command=command, version=__version__, tasks=tasks, classes=CLASSES, move=MOVE,
                  wall_s=wall_s)
    path = os.path.join(out, "FACTORS.md")
    atomic_write_text(path, text)
    return path


__all__ = ["DEFAULT_OUT", "write_report"]
