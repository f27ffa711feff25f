"""The headroom table's report (``ehss headroom``): ``HEADROOM.md`` (prose in templates/headroom.md.j2),
``headroom.csv`` and ``headroom.png``, from :func:`ehss_gym.study.headroom.run`; and with ``--causes``, ``CAUSES.md``
(templates/headroom_causes.md.j2) and ``causes.csv``, from :func:`ehss_gym.study.headroom_causes.run`."""

from __future__ import annotations

import math
import os

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from ehss_gym._version import __version__  # noqa: E402
from ehss_gym.controllers import COMPENSATOR_ROWS  # noqa: E402
from ehss_gym.evaluation.scoring import CLASSES  # noqa: E402
from ehss_gym.evaluation.specs import REFERENCE_POLICY  # noqa: E402
from ehss_gym.infra.fmt import fmt_cell  # noqa: E402
from ehss_gym.infra.util import atomic_write_text  # noqa: E402
from ehss_gym.study.headroom import (  # noqa: E402
    BASE_PERIOD,
    CHECK_SUITE,
    FREE_PERIOD,
    MATERIAL,
    MIN_EPISODES,
    VARIANTS,
)
from ehss_gym.study.headroom_causes import SUITE as CAUSE_SUITE  # noqa: E402

from .comparison import csv_text  # noqa: E402
from .render import render  # noqa: E402

DEFAULT_OUT = os.path.join("reports", "headroom")
KEYS = tuple(CLASSES) + ("figure",)  # the class figures, then the overall figure
DOB = f"dob-n2 @{BASE_PERIOD}"  # the scripted residual's row, shown per suite
# the scripted policies' rows at the base period: the best of them is shown beside the best oracle
SCRIPTED = tuple(f"{v.name} @{BASE_PERIOD}" for v in VARIANTS if v.kind == "scripted")
CORRECTION_COLUMNS = ("task", "quantity", "unit", "rms", "median_rms", "max_rms", "max_abs", "episodes")
COLUMNS = (("task", "suite", "policy", "variant", "kind", "agent_period", "failed", "n_failed", "n_used")
           + tuple(f"{k}{s}" for k in KEYS for s in ("", "_lo", "_hi")) + ("value_median", "value_moved", "observes"))


def _ci(ratio: float, lo: float, hi: float) -> str:
    """'r [lo, hi]' (n/a for an undefined ratio)."""
    if ratio is None or not math.isfinite(ratio):
        return "n/a"
    return f"{fmt_cell(ratio)} [{fmt_cell(lo)}, {fmt_cell(hi)}]"


def _headroom_cell(h: dict | None) -> str:
    """A headline cell: the best oracle's ratio with its CI and name, bold where material; '-' if no oracle is below
    1."""
    if h is None:
        return "n/a"
    if not h["ratio"] < 1.0:
        return "none (no oracle below 1)"
    cell = f"{_ci(h['ratio'], h['lo'], h['hi'])} {h['oracle']}"
    if h["few"]:
        return f"{cell} ({h['n']} episode(s): no verdict)"
    return f"**{cell}**" if h["material"] else cell


def _shown(d: dict) -> bool:
    """A row of the detail tables: every variant but the base law at other agent periods (the check's)."""
    return not (d["kind"] == "base" and d["policy"] != REFERENCE_POLICY)


def _detail_rows(block: dict) -> list[list[str]]:
    rows = []
    for d in block["stats"]:
        if not _shown(d):
            continue
        cells = [_ci(d.get(c, math.nan), d.get(f"{c}_lo"), d.get(f"{c}_hi")) for c in block["classes"]]
        gate = f"fails ({d['n_failed']})" if d["failed"] else "passes"
        val = "" if not math.isfinite(d["value_median"]) else f"{fmt_cell(d['value_median'])} ({d['value_moved']})"
        rows.append([d["policy"], *cells, _ci(d["figure"], d["figure_lo"], d["figure_hi"]), gate, val])
    return rows


def _base_rows(cfg) -> str:
    """The loop settings the study's base adds per task, in words (``--base``)."""
    return ", ".join(f"{t}: " + (", ".join(f"{k} {v}" for k, v in cfg.base_settings(t).items())
                                 or "none chosen, clf-n2 itself") for t in cfg.tasks)


def _largest(blocks: list, task: str) -> list[list[str]]:
    """Per class and overall, the largest headroom of the task over its suites (the lowest best-oracle ratio)."""
    out = []
    for key in tuple(CLASSES) + ("overall",):
        cands = [(b["suite"], b["headroom"][key]) for b in blocks if b["task"] == task and key in b["headroom"]
                 and not b["headroom"][key]["few"]]
        if not cands:
            continue
        suite, h = min(cands, key=lambda c: c[1]["ratio"])
        verdict = "material" if h["material"] else ("has headroom" if h["has"] else "none")
        fig = "figure" if key == "overall" else key
        scripted = [d for b in blocks if b["task"] == task and b["suite"] == suite for d in b["stats"]
                    if d["policy"] in SCRIPTED and not d["failed"] and math.isfinite(d.get(fig, math.nan))]
        best = min(scripted, key=lambda d: d[fig], default=None)
        out.append([key, suite, _headroom_cell(h), verdict, h["observes"] if h["ratio"] < 1.0 else "-",
                    "n/a" if best is None else
                    f"{_ci(best[fig], best.get(f'{fig}_lo'), best.get(f'{fig}_hi'))} {best['policy'].split(' @')[0]}"])
    return out


def _checks(blocks: list) -> list[list[str]]:
    """One row per (task, suite, variant) run at several agent periods: did the period change a class metric?"""
    out = []
    for b in blocks:
        for c in b["checks"]:
            same = "the same to the last bit" if c["max_rel_diff"] == 0.0 else \
                f"differ (largest relative difference {c['max_rel_diff']:.3g})"
            out.append([b["task"], b["suite"], c["variant"], ", ".join(str(p) for p in c["periods"]), same])
    return out


def plot_headroom(blocks: list, path: str, cmd: str) -> None:
    """One panel per (task, suite): each variant's class and overall figures against the base law, with 95 % CIs."""
    tasks = list(dict.fromkeys(b["task"] for b in blocks))
    suites = list(dict.fromkeys(b["suite"] for b in blocks))
    fig, axs = plt.subplots(len(tasks), len(suites), figsize=(3.6 * len(suites), 3.4 * len(tasks)), squeeze=False)
    names = [d["policy"] for d in blocks[0]["stats"] if _shown(d) and d["policy"] != REFERENCE_POLICY]
    for b in blocks:
        ax = axs[tasks.index(b["task"])][suites.index(b["suite"])]
        keys = list(b["classes"]) + ["figure"]
        for j, d in enumerate(d for d in b["stats"] if d["policy"] in names):
            x = [i + (j - len(names) / 2) * 0.06 for i in range(len(keys))]
            y = [d.get(k, math.nan) for k in keys]
            err = [[max(v - d.get(f"{k}_lo", v), 0.0) for k, v in zip(keys, y)],
                   [max(d.get(f"{k}_hi", v) - v, 0.0) for k, v in zip(keys, y)]]
            ax.errorbar(x, y, yerr=err, fmt="o", ms=3, lw=0.8, label=d["policy"], color=f"C{names.index(d['policy'])}")
        ax.axhline(1.0, color="gray", lw=0.8, ls=":")
        ax.set_yscale("log")
        ax.set_xticks(range(len(keys)))
        ax.set_xticklabels([k if k != "figure" else "overall" for k in keys], fontsize=7, rotation=30)
        ax.set_title(f"{b['task']} / {b['suite']} ({b['episodes']} ep.)", fontsize=9)
    for ax in axs.flat:
        if not ax.has_data():
            ax.set_visible(False)
    axs[0][0].set_ylabel("figure / base law (lower is better)", fontsize=8)
    handles, labels = axs[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=min(6, len(labels)), fontsize=7, frameon=False,
               bbox_to_anchor=(0.5, 0.015))
    fig.text(0.005, 0.003, f"made by: {cmd}  (ehss-gym {__version__})", fontsize=7, color="gray")
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    fig.savefig(path, dpi=80)
    plt.close(fig)


def write_report(res: dict, out: str, command: str) -> str:
    """Write HEADROOM.md, headroom.csv and headroom.png under ``out``; returns HEADROOM.md's path."""
    os.makedirs(out, exist_ok=True)
    blocks = res["blocks"]
    stats = [d for b in blocks for d in b["stats"]]
    plant = res["cfg"].plant  # a plant given: a column naming it (none: Table I's columns)
    atomic_write_text(os.path.join(out, "headroom.csv"), csv_text(stats, COLUMNS) if plant is None else
                      csv_text([{**d, "plant": plant.label} for d in stats], ("plant", *COLUMNS)))
    plot_headroom(blocks, os.path.join(out, "headroom.png"), command)
    tasks = []
    for task in dict.fromkeys(b["task"] for b in blocks):
        tb = [b for b in blocks if b["task"] == task]
        head = [[b["suite"], str(b["episodes"])] + [_headroom_cell(b["headroom"].get(k)) for k in
                                                    tuple(CLASSES) + ("overall",)] for b in tb]
        dob = [[b["suite"]] + [_ci(d.get(k, math.nan), d.get(f"{k}_lo"), d.get(f"{k}_hi")) for k in KEYS]
               for b in tb for d in b["stats"] if d["policy"] == DOB]
        details = [{"suite": b["suite"], "episodes": b["episodes"], "classes": b["classes"], "rows": _detail_rows(b)}
                   for b in tb]
        tasks.append({"task": task, "head": head, "dob": dob, "largest": _largest(blocks, task), "details": details})
    cfg = res["cfg"]
    variants = [[v.name, v.kind, _periods_text(v.periods, cfg.agent_periods), ", ".join(v.suites) or "every suite",
                 v.observes] for v in VARIANTS]
    corrections = [{"task": t, "rows": [[c["quantity"], c["unit"], fmt_cell(c["rms"]), fmt_cell(c["median_rms"]),
                                         fmt_cell(c["max_rms"]), fmt_cell(c["max_abs"])] for c in rows],
                    "episodes": max((c["episodes"] for c in rows), default=0)}
                   for t, rows in res.get("corrections", {}).items()]
    if corrections:
        atomic_write_text(os.path.join(out, "corrections.csv"),
                          csv_text([{"task": t, **c} for t, rows in res["corrections"].items() for c in rows],
                                   CORRECTION_COLUMNS))
    text = render("headroom.md.j2", command=command, version=__version__, res=res, cfg=cfg, tasks=tasks,
                  classes=CLASSES, variants=variants, checks=_checks(blocks), material=MATERIAL,
                  min_episodes=MIN_EPISODES, free_period=FREE_PERIOD, base_period=BASE_PERIOD,
                  check_suite=CHECK_SUITE, bias=cfg.bias.describe(), width=cfg.width.describe(),
                  corrections=corrections, compensators=COMPENSATOR_ROWS,
                  plant=cfg.eval_config().rig.text(), base=cfg.base, base_rows=_base_rows(cfg))
    path = os.path.join(out, "HEADROOM.md")
    atomic_write_text(path, text)
    return path


def _join(names) -> str:
    return ", ".join(names) or "-"


def _cause_tables(t: dict, causes: tuple) -> dict:
    """One task of the cause split: the overall figure of every variant on every version of the episodes (CI on the
    episodes as they are), and the rule's verdict per variant."""
    versions = list(t["versions"])
    names = [d["policy"] for d in t["versions"][versions[0]]]
    by = {v: {d["policy"]: d for d in stats} for v, stats in t["versions"].items()}
    figures = []
    for n in names:
        d0 = by[versions[0]][n]
        cells = [_ci(d0["figure"], d0["figure_lo"], d0["figure_hi"])]
        cells += [fmt_cell(by[v][n]["figure"]) if n in by[v] else "n/a" for v in versions[1:]]
        figures.append([n, *cells])
    verdicts = []
    for n, vd in t["verdicts"].items():
        share = vd["removed_share"]
        verdicts.append([n, vd["gap"], _join(vd["explained"]), _join(vd["mostly"]), _join(vd["widens"]),
                         *[fmt_cell(share[c]) if c in share else "-" for c in causes]])
    return {"task": t["task"], "episodes": t["episodes"], "versions": versions, "figures": figures,
            "verdicts": verdicts}


def write_causes(res: dict, out: str, command: str) -> str:
    """Write CAUSES.md and causes.csv under ``out``; returns CAUSES.md's path."""
    os.makedirs(out, exist_ok=True)
    rows = [{**d, "version": v} for t in res["tasks"] for v, stats in t["versions"].items() for d in stats]
    atomic_write_text(os.path.join(out, "causes.csv"), csv_text(rows, ("version", *COLUMNS)))
    causes = tuple(res["causes"])
    text = render("headroom_causes.md.j2", command=command, version=__version__, res=res, cfg=res["cfg"],
                  suite=CAUSE_SUITE, causes=causes, tasks=[_cause_tables(t, causes) for t in res["tasks"]],
                  plant=res["cfg"].eval_config().rig.text(), base=res["cfg"].base, base_rows=_base_rows(res["cfg"]))
    path = os.path.join(out, "CAUSES.md")
    atomic_write_text(path, text)
    return path


def _periods_text(periods: str, agent_periods: tuple) -> str:
    every = ", ".join(str(p) for p in agent_periods)
    return {"all": every, "free": f"{FREE_PERIOD} (cannot matter)",
            "check": f"{BASE_PERIOD}; {every} on {CHECK_SUITE} (the check)"}[periods]


__all__ = ["DEFAULT_OUT", "COLUMNS", "plot_headroom", "write_report", "write_causes"]
