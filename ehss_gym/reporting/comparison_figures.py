"""Figures of the policy comparison (``ehss evaluate``): Pareto figures of the class figures, held-out metric bars,
paper-run traces and robustness curves, each PNG written atomically with the command that made it in its footer
(their captions are in templates/comparison.md.j2)."""

from __future__ import annotations

import math
import os
import re
from collections.abc import Sequence

import numpy as np

from ehss_gym._version import __version__
from ehss_gym.evaluation import stats
from ehss_gym.evaluation.harness import Results
from ehss_gym.evaluation.scoring import FIGURE_SUITES, matrix
from ehss_gym.evaluation.specs import REFERENCE_POLICY
from ehss_gym.evaluation.suites import TASKS, UNITS
from ehss_gym.infra.util import atomic_write

from .trajectory_figures import plt

DPI = 90
FIGURE_KINDS = ("pareto", "traces", "robustness", "metrics")
ZOOM_BEFORE, ZOOM_AFTER = 0.3, 2.6  # [s] the trace zoom around the first friction switch-on


def _footer(fig, res: Results) -> None:
    """The made-by line (command and version) at the bottom left."""
    fig.text(0.01, 0.005, f"made by: {res.command}  (ehss-gym {__version__})", fontsize=7, color="gray")


def _finish(fig, res: Results, folder: str, name: str, bottom: float) -> str:
    """Footer, layout (``bottom`` left for the footer), atomic PNG write and close; returns the path relative
    to the report."""
    _footer(fig, res)
    fig.tight_layout(rect=(0, bottom, 1, 1))
    atomic_write(os.path.join(folder, name), lambda f: fig.savefig(f, format="png", dpi=DPI))
    plt.close(fig)
    return os.path.join("figures", name)


# 18 colours that stay apart from each other (tab10, then darker and lighter hues that tab10 lacks); the policies
# past them repeat a colour with another line style, so every policy has its own look in every figure
PALETTE = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22",
           "#17becf", "#393b79", "#637939", "#8c6d31", "#843c39", "#7b4173", "#3182bd", "#31a354", "#000000")
LINESTYLES = ("-", "--", ":", "-.")
MARKERS = ("o", "s", "^", "v", "D", "P", "X", "*")


def _colors(names: Sequence[str]) -> dict:
    """One colour per policy name, in spec order (the same colour in every figure); distinct for up to
    len(PALETTE) policies."""
    return {n: PALETTE[i % len(PALETTE)] for i, n in enumerate(names)}


def _styles(names: Sequence[str]) -> dict:
    """Per policy name: (colour, line style, marker), unique for every policy (spec order)."""
    return {n: (PALETTE[i % len(PALETTE)], LINESTYLES[(i // len(PALETTE)) % len(LINESTYLES)], MARKERS[i % len(MARKERS)])
            for i, n in enumerate(names)}


LABEL_CHARS = 34  # bar charts: a longer policy name is wrapped at its commas (a law at a learned policy's settings)
CHAR_WIDTH = 0.065  # [in] of a character of the 8-point tick labels, a bound on DejaVu Sans's mean width
LINE_HEIGHT = 0.15  # [in] of a line of those labels


def _wrap(name: str) -> str:
    """A policy name in lines of at most :data:`LABEL_CHARS` characters, broken after its commas and its '@'."""
    lines, cur = [], ""
    for part in re.split(r"(?<=[,@])", name):
        if cur and len(cur) + len(part) > LABEL_CHARS:
            lines.append(cur)
            cur = part
        else:
            cur += part
    return "\n".join([*lines, cur])


def _label_size(names: Sequence[str]) -> tuple[float, int]:
    """(width [in] of the widest wrapped tick label, most lines of one) for the bar charts' figure sizes."""
    wrapped = [_wrap(n).split("\n") for n in names] or [[""]]
    return max(len(line) for w in wrapped for line in w) * CHAR_WIDTH, max(len(w) for w in wrapped)


def _legend_outside(fig, ax, ncol: int = 1) -> None:
    """The legend of ``ax``'s lines to the right of the axes, off the data."""
    handles, labels = ax.get_legend_handles_labels()
    if handles:
        ax.legend(handles, labels, fontsize=7, ncol=ncol, loc="upper left", bbox_to_anchor=(1.01, 1.0),
                  borderaxespad=0.0, frameon=False)


def _xy_err(d: dict, key: str) -> tuple[float, float, float]:
    """(figure, distance to its CI's low end, to its high end) of a summary row (CI over seeds and episodes with
    several runs); NaNs where the class is absent."""
    v = d.get(key, math.nan)
    tag = "_both" if f"{key}_lo_both" in d else ""
    lo, hi = d.get(f"{key}_lo{tag}", math.nan), d.get(f"{key}_hi{tag}", math.nan)
    return v, max(v - lo, 0.0), max(hi - v, 0.0)


PARETO = (("effort", "tracking"), ("effort", "disturbance"))  # (x, y) classes of the Pareto panels


def _pareto(res: Results, folder: str, col: dict, suite: str):
    """Per task, the tracking and the disturbance figure against the effort figure, one point per policy with its
    95 % CIs (hollow: recorded in an earlier loop, not ranked): (path, suite), or None if the suite did not run."""
    tasks = [t for t in TASKS if any(d["suite"] == suite and d["task"] == t for d in res.summary)]
    if not tasks:
        return None
    names = [s.name for s in res.specs]
    sty = _styles(names)
    fig, axes = plt.subplots(len(tasks), len(PARETO), figsize=(11, 4.3 * len(tasks)), squeeze=False)
    for row, task in zip(axes, tasks):
        block = [d for d in res.summary if d["suite"] == suite and d["task"] == task]
        for ax, (xc, yc) in zip(row, PARETO):
            for d in block:
                x, xlo, xhi = _xy_err(d, xc)
                y, ylo, yhi = _xy_err(d, yc)
                if not (math.isfinite(x) and math.isfinite(y)):
                    continue
                c, _, mk = sty[d["policy"]]
                ax.errorbar([x], [y], xerr=[[xlo], [xhi]], yerr=[[ylo], [yhi]], color=c, marker=mk, ms=6,
                            mfc="none" if d["earlier_loop"] else c, lw=0, elinewidth=0.9, capsize=2,
                            label=d["policy"] + (" (earlier loop)" if d["earlier_loop"] else "")
                            + (" FAILED" if d["failed"] else ""))
            ax.axvline(1.0, color="gray", ls="--", lw=0.8)
            ax.axhline(1.0, color="gray", ls="--", lw=0.8)
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_xlabel(f"{xc} figure ({REFERENCE_POLICY} = 1; lower is better)", fontsize=8)
            ax.set_ylabel(f"{yc} figure", fontsize=8)
            ax.set_title(f"{suite} suite, {task}", fontsize=9)
        _legend_outside(fig, row[-1])
    return _finish(fig, res, folder, f"pareto_{suite}.png", 0.02), suite


def _mean_ci(res: Results, v: np.ndarray) -> tuple[float, float, float]:
    """Mean of the finite values ``v`` with a 95 % bootstrap CI (NaNs if none)."""
    v = v[np.isfinite(v)]
    if not v.size:
        return math.nan, math.nan, math.nan
    lo, hi = stats.bootstrap_ci(v, "mean", n_boot=res.cfg.n_boot, seed=res.cfg.seed)
    return float(v.mean()), lo, hi


def _metric_bars(res: Results, folder: str, col: dict, task: str):
    """Held-out tracking RMSE, disturbance peak and control TV per policy: (path, task), or None if the
    suite did not run."""
    block = [d for d in res.summary if d["suite"] == "heldout" and d["task"] == task]
    if not block:
        return None
    keys = (("trk_rmse", f"tracking RMSE [{UNITS[task]}]"), ("dst_peak", f"disturbance peak [{UNITS[task]}]"),
            ("tv_u_rate", "control TV [mA/s]"))
    label_w, lines = _label_size([d["policy"] for d in block])
    row = max(0.4, LINE_HEIGHT * lines + 0.15)
    # the policy names once, on the first panel (the three share the rows)
    fig, axes = plt.subplots(1, 3, figsize=(14 + label_w, row * len(block) + 2.2), sharey=True)
    block.reverse()  # the first-ranked at the top
    for ax, (key, label) in zip(axes, keys):
        vals, los, his = [], [], []
        for d in block:
            mean, lo, hi = _mean_ci(res, matrix(res.rows, d["policy"], "heldout", task, key)[0])
            vals.append(mean)
            los.append(mean - lo)
            his.append(hi - mean)
        y = np.arange(len(block))
        ax.barh(y, vals, xerr=[los, his], color=[col[d["policy"]] for d in block], alpha=0.8, capsize=3)
        ax.set_yticks(y, [_wrap(d["policy"]) for d in block], fontsize=8)
        ax.set_xlabel(label)
        fin = [v for v in vals if math.isfinite(v) and v > 0]
        if fin and max(fin) / min(fin) > 30:
            ax.set_xscale("log")
        else:
            ax.ticklabel_format(axis="x", style="sci", scilimits=(-2, 3))
    fig.suptitle(f"Held-out suite, {task}: mean over episodes (non-diverged) with 95 % bootstrap CI", fontsize=9)
    return _finish(fig, res, folder, f"metrics_heldout_{task}.png", 0.03), task


def _paper_traces(res: Results, folder: str, col: dict, task: str):
    """Output, error (full and zoomed on the friction event) and current of every policy on the paper run (first
    training seed): (path, task), or None if the paper suite did not run."""
    names = [s.name for s in res.specs]
    tr = {n: res.traces[(n, 0, task)] for n in names if (n, 0, task) in res.traces}
    if not tr:
        return None
    unit = UNITS[task]
    ep = next(e for e in res.episodes if e.suite == "paper" and e.task == task)
    fr = [ev for ev in ep.physical["friction"] if ev[0] > 0]
    t_on = fr[0][1] if fr else 0.0
    zoom = (max(0.0, t_on - ZOOM_BEFORE), t_on + ZOOM_AFTER) if fr else (0.0, ep.t_end)
    fig, ax = plt.subplots(4, 1, figsize=(12, 11))
    first = next(iter(tr.values()))
    sty = _styles(names)
    ax[0].plot(first["t"], first["y_ref"], color="0.2", ls=(0, (1, 1)), lw=1.6, label="reference $y_d$")
    for n, d in tr.items():
        c, ls, _ = sty[n]
        ax[0].plot(d["t"], d["y"], lw=0.8, color=c, ls=ls, label=n)
        ax[1].plot(d["t"], d["e"], lw=0.7, color=c, ls=ls, label=n)
        sel = (d["t"] >= zoom[0]) & (d["t"] <= zoom[1])
        ax[2].plot(d["t"][sel], d["e"][sel], lw=0.8, color=c, ls=ls, label=n)
        ax[3].plot(d["t"][sel], d["u"][sel], lw=0.6, color=c, ls=ls, label=n)
    ax[0].set_ylabel(f"output [{unit}]")
    ax[1].set_ylabel(f"error e [{unit}]")
    ax[2].set_ylabel(f"e [{unit}] (zoom)")
    ax[3].set_ylabel("applied u [mA] (zoom)")
    ax[3].set_xlabel("time [s]")
    for a in ax[2:]:
        for ev in fr:
            a.axvspan(ev[1], ev[2], color="orange", alpha=0.12)
    ax[1].axhline(0, color="gray", lw=0.5)
    _legend_outside(fig, ax[0])
    fig.suptitle(f"Paper scenario, {task} task: every policy overlaid (first training seed); friction shaded",
                 fontsize=9)
    return _finish(fig, res, folder, f"paper_traces_{task}.png", 0.02), task


def _sweep_curve(res: Results, pr: list, key: str) -> tuple[list, list, list, list]:
    """(levels, means, CI lows, CI highs) of ``key`` over the non-diverged rows ``pr`` of one policy and sweep."""
    xs, ms, los, his = [], [], [], []
    for lv in sorted({r["level"] for r in pr}):
        v = np.array([r[key] for r in pr if r["level"] == lv and not r["diverged"]], dtype=float)
        v = v[np.isfinite(v)]
        if not v.size:
            continue
        xs.append(lv)
        ms.append(v.mean())
        if v.size > 1:
            lo, hi = stats.bootstrap_ci(v, "mean", n_boot=res.cfg.n_boot, seed=res.cfg.seed)
        else:
            lo = hi = float(v.mean())
        los.append(lo)
        his.append(hi)
    return xs, ms, los, his


def _robustness(res: Results, folder: str, col: dict, task: str):
    """Error and control TV against friction amplitude and model mismatch per policy: (path, task), or None if
    the sweeps did not run."""
    rr = [r for r in res.rows if r["suite"] == "robustness" and r["task"] == task]
    if not rr:
        return None
    u = UNITS[task]
    panels = (("friction", "dst_peak", "friction amplitude [N m]", f"disturbance peak [{u}]"),
              ("friction", "trk_rmse", "friction amplitude [N m]", f"tracking RMSE [{u}]"),
              ("mismatch", "trk_rmse", "plant-parameter mismatch [+-]", f"tracking RMSE [{u}]"),
              ("mismatch", "tv_u_rate", "plant-parameter mismatch [+-]", "control TV [mA/s]"))
    names = [s.name for s in res.specs]
    sty = _styles(names)
    fig, axes = plt.subplots(2, 2, figsize=(13, 8))
    for ax, (sweep, key, xl, yl) in zip(axes.ravel(), panels):
        levels = sorted({r["level"] for r in rr if r["sweep"] == sweep})
        step = min(np.diff(levels)) if len(levels) > 1 else 1.0
        for i, n in enumerate(names):
            pr = [r for r in rr if r["policy"] == n and r["sweep"] == sweep]
            if not pr:
                continue
            xs, ms, los, his = _sweep_curve(res, pr, key)
            if xs:  # dodged sideways (a 1/3 of a level step shared by all) so the CI bars do not hide each other
                x = np.asarray(xs) + step * (i / max(len(names) - 1, 1) - 0.5) / 3.0
                c, ls, mk = sty[n]
                ax.errorbar(x, ms, yerr=[np.subtract(ms, los), np.subtract(his, ms)], color=c, ls=ls, marker=mk,
                            lw=1.0, ms=3.5, elinewidth=0.7, capsize=1.5, label=n)
        ax.set_xticks(levels)
        ax.set_xlabel(xl)
        ax.set_ylabel(yl)
        ax.set_yscale("log")
    _legend_outside(fig, axes[0, 1])
    fig.suptitle(f"Robustness, {task}: mean over {res.cfg.sweep_episodes} episodes per level (bars: 95 % bootstrap "
                 "CI, policies side by side at each level; diverged episodes left out)", fontsize=9)
    return _finish(fig, res, folder, f"robustness_{task}.png", 0.02), task


def make_figures(res: Results, folder: str) -> dict:
    """Every figure of the comparison, written under ``folder``.

    Args:
        res: the evaluation's results.
        folder: the report's figures/ folder.

    Returns:
        kind ("pareto", "traces", "robustness", "metrics") -> list of (path relative to the report, what it shows:
        the suite for "pareto", the task otherwise); the captions are the template's.
    """
    col = _colors([s.name for s in res.specs])
    made = {"pareto": [_pareto(res, folder, col, suite) for suite in FIGURE_SUITES],
            "metrics": [_metric_bars(res, folder, col, task) for task in TASKS],
            "traces": [_paper_traces(res, folder, col, task) for task in TASKS],
            "robustness": [_robustness(res, folder, col, task) for task in TASKS]}
    return {k: [f for f in made[k] if f is not None] for k in FIGURE_KINDS}


__all__ = ["make_figures"]
