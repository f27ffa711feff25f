"""``ehss baselines``'s report: ``tuned.json`` (every baseline's tuned settings, objective, evaluations used and
every evaluated point), ``law_settings.json`` (the law table that ``--law-settings`` and the env's ``law_settings``
take, :mod:`ehss_gym.envs.law_table`), ``BASELINES.md`` (prose in templates/baselines.md.j2) and one convergence
figure per task, from :func:`ehss_gym.study.baselines.tune`."""

from __future__ import annotations

import json
import math
import os

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from ehss_gym._version import __version__  # noqa: E402
from ehss_gym.evaluation.scoring import CLASSES  # noqa: E402
from ehss_gym.infra.fmt import fmt_cell  # noqa: E402
from ehss_gym.infra.util import atomic_write_text  # noqa: E402
from ehss_gym.study.baselines import BASELINES, KEEP_MARGIN  # noqa: E402
from ehss_gym.study.compensators import TIE  # noqa: E402
from ehss_gym.study.friction_windows import LIMIT_CYCLE_REVERSALS, SATURATION_MAX  # noqa: E402

from .render import render  # noqa: E402

DEFAULT_OUT = os.path.join("reports", "baselines")
LAW_SETTINGS_FILE = "law_settings.json"  # the law table (ehss_gym.envs.law_table) that --law-settings takes


def _best_so_far(evals: list) -> list[float]:
    """The incumbent's objective after each evaluation (NaN while no feasible point was found)."""
    out, best = [], math.inf
    for e in evals:
        if not e["failed"] and e["objective"] < best:
            best = e["objective"]
        out.append(best if math.isfinite(best) else math.nan)
    return out


def plot_convergence(results: list, task: str, path: str, cmd: str) -> None:
    """Best feasible objective so far against the evaluation count, one line per baseline of ``task``."""
    fig, ax = plt.subplots(figsize=(7.5, 4.2))
    for r in results:
        ev = r["evaluations"]
        ax.plot(range(1, len(ev) + 1), _best_so_far(ev), drawstyle="steps-post", label=r["policy"])
        ax.scatter(range(1, len(ev) + 1), [e["objective"] if not e["failed"] else math.nan for e in ev], s=6,
                   alpha=0.35)
    ax.axhline(1.0, color="gray", lw=0.8, ls=":")
    ax.set_yscale("log")
    ax.set_xlabel("evaluation")
    ax.set_ylabel("overall figure G against the anchor (lower is better)")
    ax.set_title(f"{task} task: best feasible objective so far (dots: each evaluation)", fontsize=10)
    ax.legend(fontsize=8)
    fig.text(0.005, 0.003, f"made by: {cmd}", fontsize=7, color="gray")
    fig.tight_layout(rect=(0, 0.02, 1, 1))
    fig.savefig(path, dpi=85)
    plt.close(fig)


def _settings_rows(results: list) -> list[list[str]]:
    rows = []
    for r in results:
        tuned = ", ".join(f"{k} = {fmt_cell(v)}" for k, v in r["tuned"].items())
        fixed = ", ".join(f"{k} = {fmt_cell(v)}" for k, v in r["fixed"].items()) or "-"
        rows.append([r["policy"], fixed, tuned, fmt_cell(r["objective"]),
                     *[fmt_cell(r["classes"].get(c, math.nan)) for c in CLASSES],
                     "FAILED" if r["failed"] else "ok", str(r["evaluations_used"])])
    return rows


def _check_rows(check: dict) -> list[list[str]]:
    """The held-out check's table: per task the tuned and the untuned n = 2 law."""
    rows = []
    for task, d in check.items():
        for which in ("tuned", "untuned"):
            c = d[which]
            rows.append([task, which, f"{c['saturation']:.2%}", f"{c['saturation_max']:.2%}", str(c["windows"]),
                         str(c["limit_cycles"]), str(c["reversals_max"]), f"{c['window_saturation_max']:.2%}",
                         str(c["failed"]), "pass" if c["passed"] else "FAIL"])
    return rows


def _compensator_rows(comp: dict) -> list[list[str]]:
    """The compensators' table: per task and compensator the lowest G, the chosen size and its G."""
    rows = []
    for task, kinds in comp.items():
        for kind, r in kinds.items():
            failed = sum(e["failed"] for e in r["evaluations"])
            rows.append([task, f"{kind}-n2", _point(r["best"]), fmt_cell(r["best_figure"]),
                         _point(r["chosen"]) if any(r["chosen"].values()) else "none", fmt_cell(r["figure"]),
                         f"{failed} of {len(r['evaluations'])}"])
    return rows


def _point(p: dict) -> str:
    return ", ".join(f"{k} = {v:g}" for k, v in p.items())


def write_report(res: dict, out: str, command: str, wall_s: float) -> str:
    """Write tuned.json, law_settings.json, BASELINES.md and convergence_<task>.png under ``out``; returns
    BASELINES.md's path."""
    os.makedirs(out, exist_ok=True)
    atomic_write_text(os.path.join(out, "tuned.json"),
                      json.dumps({"command": command, "version": __version__, **res}, indent=1) + "\n")
    if any(t in res["law_settings"] for t in ("velocity", "position")):
        atomic_write_text(os.path.join(out, LAW_SETTINGS_FILE), json.dumps(
            {"made_by": command, "version": __version__, **res["law_settings"]}, indent=1) + "\n")
    tasks = []
    for task in dict.fromkeys(r["task"] for r in res["baselines"].values()):
        results = [r for r in res["baselines"].values() if r["task"] == task]
        fig = f"convergence_{task}.png"
        plot_convergence(results, task, os.path.join(out, fig), command)
        spaces = [[r["policy"], "; ".join(f"{k}: {v}" for k, v in r["space"].items())] for r in results]
        tasks.append({"task": task, "table": _settings_rows(results), "spaces": spaces, "figure": fig,
                      "anchor": res["anchor"][task], "defaults": res["defaults"].get(task)})
    rows = {r.name: r for r in BASELINES}
    text = render("baselines.md.j2", command=command, version=__version__, wall_s=wall_s, tasks=tasks,
                  settings=res["settings"], classes=CLASSES, margin=KEEP_MARGIN, n_rows=len(res["baselines"]),
                  runners=sorted({rows[n].runner for n in res["baselines"] if n in rows}), plant=res["plant"],
                  check=_check_rows(res["check"]), law_file=LAW_SETTINGS_FILE if res["check"] or any(
                      t in res["law_settings"] for t in ("velocity", "position")) else None,
                  saturation_max=SATURATION_MAX, reversals=LIMIT_CYCLE_REVERSALS,
                  compensators=_compensator_rows(res.get("compensators") or {}), tie=TIE,
                  compensator_episodes=res["settings"].get("compensator_episodes", 0))
    path = os.path.join(out, "BASELINES.md")
    atomic_write_text(path, text)
    return path


__all__ = ["LAW_SETTINGS_FILE", "DEFAULT_OUT", "plot_convergence", "write_report"]
