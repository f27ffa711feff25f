"""The policy comparison report of ``ehss evaluate``: numbers, tables and CSVs computed here, prose in
templates/comparison.md.j2, figures in :mod:`ehss_gym.reporting.comparison_figures`.

:func:`write_report` writes ``REPORT.md``, ``episodes.csv``, ``summary.csv``, ``comparisons.csv`` and ``figures/``
for the :class:`~ehss_gym.evaluation.harness.Results` of :func:`ehss_gym.evaluation.evaluate`.
"""

from __future__ import annotations

import csv
import io
import math
import os
import time
from collections.abc import Sequence

from ehss_gym._version import __version__
from ehss_gym.envs import EnvConfig
from ehss_gym.evaluation.harness import Results
from ehss_gym.evaluation.scoring import METRIC_KEYS, METRICS, RATE_KEYS, SCORE_CAP
from ehss_gym.evaluation.specs import REFERENCE_POLICY
from ehss_gym.evaluation.suites import (
    ROBUST_SEED_START,
    SUITES,
    SWEEP_MISMATCH_FRICTION,
    SWEEP_WINDOW,
    TASKS,
    UNITS,
)
from ehss_gym.infra.fmt import fmt_cell
from ehss_gym.infra.util import atomic_write_text

from .comparison_figures import FIGURE_KINDS, make_figures
from .render import render

DEFAULT_OUT = os.path.join("reports", "comparison")
TEMPLATE = "comparison.md.j2"
EPISODE_COLUMNS = ("suite", "task", "policy", "run", "episode", "sweep", "level", "scenario_seed", "t_end", "score",
                   "score_normaliser") + METRIC_KEYS + ("peak_u", "tv_u", "divergence_reason", "t_diverged",
                                                        "t_lost_track", "n_clipped")


def fmt(x, digits: int = 3) -> str:
    """A table cell (:func:`ehss_gym.infra.fmt.fmt_cell`: scientific below 1e-3 and from 1e4)."""
    return fmt_cell(x, digits)

def _md(text: str) -> str:
    """Escape the pipes of |e| inside a markdown table cell."""
    return str(text).replace("|", "\\|")


def _csv_cell(v) -> str:
    """One CSV cell: floats by ``repr`` (exact), non-finite as nan/inf/-inf, None as empty."""
    if isinstance(v, float):
        if math.isfinite(v):
            return repr(v)
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf")
    return "" if v is None else str(v)


def csv_text(rows: list, columns: Sequence[str]) -> str:
    """Dict rows as CSV (floats at full precision: ``repr``; missing keys empty)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(columns)
    for r in rows:
        w.writerow([_csv_cell(r.get(c, "")) for c in columns])
    return buf.getvalue()


def _columns(dicts: list) -> list[str]:
    """Every key of the dicts, in first-seen order."""
    return list(dict.fromkeys(k for d in dicts for k in d))


def _policy_rows(res: Results) -> list[list]:
    """Rows of the policies table: name, kind, runs, tasks, env settings, source."""
    out = []
    for s in res.specs:
        kw = ", ".join(f"{k}={v!r}" for k, v in sorted(s.env_kwargs.items())) or "defaults"
        out.append([s.name, s.kind, len(s.runs), ", ".join(s.tasks), kw, s.source])
    return out


def _env_rows(res: Results) -> list[list]:
    """Rows of the env-defaults table, one per evaluated task (frequencies [Hz], currents [mA], periods [s])."""
    out = []
    for task in res.cfg.tasks:
        c = EnvConfig.from_kwargs({"task": task})
        out.append([task, f"{c.fr:g}", f"{c.sigma:g}", f"{c.smoothing:g}", c.current_limit, f"{c.control_period:g}",
                    c.substeps, c.agent_period, f"{c.estimator_hz:g}", f"{c.residual_scale:g}"])
    return out


def _ranking_row(d: dict) -> list:
    """One row of a ranking table from a summary row (scores [-], errors [output unit], TV [mA/s])."""
    ci = f"{fmt(d['score_mean'])} [{fmt(d['score_mean_lo'])}, {fmt(d['score_mean_hi'])}]"
    if "score_mean_lo_seeds" in d:
        ci += f"; seeds [{fmt(d['score_mean_lo_seeds'])}, {fmt(d['score_mean_hi_seeds'])}]"
    iq = f"{fmt(d['score_iqm'])} [{fmt(d['score_iqm_lo'])}, {fmt(d['score_iqm_hi'])}]"
    poi = "-" if math.isnan(d["poi_vs_best_clf"]) else \
        f"{d['poi_vs_best_clf']:.2f} [{d['poi_lo']:.2f}, {d['poi_hi']:.2f}]"
    return [d["rank"], d["policy"], ci, iq, poi, fmt(d["rmse"]), fmt(d["max_abs_e_friction"]), fmt(d["tv_u_rate"]),
            fmt(d["saturation"]), f"{d['divergence_rate']:.0%}", f"{d['lost_track_rate']:.0%}"]


def _ranking_blocks(res: Results) -> list[dict]:
    """One ranking table per (suite, task) that ran: its labels and rows."""
    out = []
    for suite in SUITES:
        for task in TASKS:
            block = [d for d in res.summary if d["suite"] == suite and d["task"] == task]
            if block:
                out.append({"suite": suite, "task": task, "unit": UNITS[task], "n_episodes": block[0]["n_episodes"],
                            "best_clf": block[0]["best_clf"], "rows": [_ranking_row(d) for d in block]})
    return out


def _metric_table(res: Results) -> tuple[list, list]:
    """(header, rows) of the all-metrics table: means over the non-diverged episodes, the divergence and lost-track
    rates."""
    hdr = (["suite", "task", "policy"] + [k for k in METRIC_KEYS if k not in RATE_KEYS]
           + [RATE_KEYS[k] for k in METRIC_KEYS if k in RATE_KEYS])
    rows = []
    for d in res.summary:
        vals = [d["suite"], d["task"], d["policy"]]
        for k in hdr[3:]:
            v = fmt(d.get(k))
            if k.startswith("recovery") and d.get(k + "_never"):
                v += f" ({d[k + '_never']} never)"
            vals.append(v)
        rows.append(vals)
    return hdr, rows


def _comparison_rows(res: Results) -> list[list]:
    """Rows of the learned-against-scripted table (improvements and ratios [-])."""
    return [[c["suite"], c["task"], c["policy"], c["n_runs"], c["score_reference"], c["best_clf"],
             f"{c['improvement']:+.1%} [{c['improvement_lo']:+.1%}, {c['improvement_hi']:+.1%}]",
             f"{c['poi']:.2f} [{c['poi_lo']:.2f}, {c['poi_hi']:.2f}]",
             c["base_law"], fmt(c.get("rmse_ratio")), fmt(c.get("tv_ratio")), fmt(c.get("friction_peak_ratio"))]
            for c in res.comparisons]


def report_context(res: Results, figs: dict) -> dict:
    """Everything templates/comparison.md.j2 shows: settings, numbers and table rows (as cell strings).

    Args:
        res: the evaluation's results.
        figs: what :func:`~ehss_gym.reporting.comparison_figures.make_figures` returned (kind -> (path, suite or
            task) pairs; the template words the captions).
    """
    metric_header, metric_rows = _metric_table(res)
    return {
        "command": res.command, "version": __version__, "n_episodes": len(res.rows), "workers": res.workers,
        "wall_time": res.wall_time, "timings": ", ".join(f"{k} {v:.1f} s" for k, v in res.timings.items()),
        "learned": any(s.learned for s in res.specs), "notes": list(res.notes), "cfg": res.cfg,
        "policy_rows": _policy_rows(res), "env_rows": _env_rows(res),
        "reference": REFERENCE_POLICY, "score_cap": SCORE_CAP, "robust_seed_start": ROBUST_SEED_START,
        "sweep_window": SWEEP_WINDOW, "mismatch_friction": SWEEP_MISMATCH_FRICTION,
        "metric_rows": [[f"{_md(label)} (`{key}`)", unit, _md(text)] for key, label, unit, text in METRICS],
        "blocks": _ranking_blocks(res), "metric_header": metric_header, "all_metric_rows": metric_rows,
        "figs": {k: list(figs.get(k, [])) for k in FIGURE_KINDS}, "comparison_rows": _comparison_rows(res),
    }


def report_text(res: Results, figs: dict) -> str:
    """The markdown report (templates/comparison.md.j2 filled with :func:`report_context`)."""
    return render(TEMPLATE, **report_context(res, figs))


def write_report(res: Results, out: str) -> str:
    """Write REPORT.md, episodes.csv, summary.csv, comparisons.csv and figures/ under ``out``; returns REPORT.md.

    Every file is written atomically; REPORT.md last, so an interrupted run leaves the previous report. The
    figures' wall time [s] is added to ``res.timings["figures"]``.
    """
    os.makedirs(os.path.join(out, "figures"), exist_ok=True)
    atomic_write_text(os.path.join(out, "episodes.csv"), csv_text(res.rows, EPISODE_COLUMNS))
    atomic_write_text(os.path.join(out, "summary.csv"), csv_text(res.summary, _columns(res.summary)))
    if res.comparisons:
        atomic_write_text(os.path.join(out, "comparisons.csv"), csv_text(res.comparisons, _columns(res.comparisons)))
    t0 = time.perf_counter()
    figs = make_figures(res, os.path.join(out, "figures"))
    res.timings["figures"] = time.perf_counter() - t0
    text = report_text(res, figs)
    path = os.path.join(out, "REPORT.md")
    atomic_write_text(path, text)
    return path


__all__ = ["DEFAULT_OUT", "EPISODE_COLUMNS", "fmt", "csv_text", "report_context", "report_text", "write_report"]
