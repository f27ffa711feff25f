"""The factor table's report (``ehss factors``): ``FACTORS.md`` (prose in templates/factors.md.j2), ``factors.csv``
and ``rankings.csv``, from :func:`ehss_gym.study.factors.run` and :func:`ehss_gym.study.factors.rankings`."""

from __future__ import annotations

import os

from ehss_gym._version import __version__
from ehss_gym.core.sim import UNITS
from ehss_gym.evaluation.scoring import CLASSES, NUMERIC_FLOORS, PHYSICAL_FLOORS
from ehss_gym.infra.fmt import fmt_cell
from ehss_gym.infra.util import atomic_write_text
from ehss_gym.study.factors import MOVE

from .comparison import csv_text
from .render import render

DEFAULT_OUT = os.path.join("reports", "factors")
COLUMNS = (("task", "factor") + CLASSES + tuple(f"{c}_ratio" for c in CLASSES) + tuple(f"{c}_numeric" for c in CLASSES)
           + tuple(f"{c}_numeric_ratio" for c in CLASSES))
RANK_COLUMNS = ("suite", "task", "floors", "figure", "rank", "policy", "value")


def _rows(t: dict, tag: str = "") -> list[list[str]]:
    """One table row per factor: each class's level and, in brackets, its ratio to the suite as it is (``tag``:
    "" for the physical floors, "_numeric" for the numeric ones)."""
    return [[r["factor"]] + [f"{fmt_cell(r[c + tag])} ({fmt_cell(r[f'{c}{tag}_ratio'])}x)" for c in CLASSES]
            for r in t["rows"]]


def _order_text(order: list) -> str:
    return "; ".join(f"{k}. {n} {fmt_cell(g)}" for k, (n, g) in enumerate(order, 1))


def rank_lines(ranks: list[dict]) -> list[dict]:
    """Per (suite, task): per figure the order under each floor set, marked where it differs."""
    out = []
    for r in ranks:
        figs = []
        for f, phys in r["orders"]["physical"].items():
            num = r["orders"]["numeric"].get(f, [])
            figs.append({"figure": f, "changed": f in r["changed"], "physical": _order_text(phys),
                         "numeric": _order_text(num)})
        out.append({"suite": r["suite"], "task": r["task"], "figures": figs, "changed": r["changed"]})
    return out


def _rank_csv(ranks: list[dict]) -> str:
    flat = [{"suite": r["suite"], "task": r["task"], "floors": fl, "figure": f, "rank": k, "policy": n, "value": g}
            for r in ranks for fl, orders in r["orders"].items() for f, order in orders.items()
            for k, (n, g) in enumerate(order, 1)]
    return csv_text(flat, RANK_COLUMNS)


def write_report(results: list[dict], out: str, command: str, wall_s: float, ranks: list[dict] = ()) -> str:
    """Write FACTORS.md, factors.csv and rankings.csv under ``out``; returns FACTORS.md's path."""
    os.makedirs(out, exist_ok=True)
    flat = [{"task": t["task"], **r} for t in results for r in t["rows"]]
    atomic_write_text(os.path.join(out, "factors.csv"), csv_text(flat, COLUMNS))
    if ranks:
        atomic_write_text(os.path.join(out, "rankings.csv"), _rank_csv(list(ranks)))
    tasks = [{**t, "unit": UNITS[t["task"]], "table": _rows(t), "numeric_table": _rows(t, "_numeric")}
             for t in results]
    text = render("factors.md.j2", command=command, version=__version__, tasks=tasks, classes=CLASSES, move=MOVE,
                  wall_s=wall_s, floors=PHYSICAL_FLOORS.rows(), numeric=NUMERIC_FLOORS.rows(),
                  ranks=rank_lines(list(ranks)))
    path = os.path.join(out, "FACTORS.md")
    atomic_write_text(path, text)
    return path


__all__ = ["DEFAULT_OUT", "write_report", "rank_lines"]
