"""The policy comparison report of ``ehss evaluate``: numbers, tables and CSVs computed here, prose in
templates/comparison.md.j2, figures in :mod:`ehss_gym.reporting.comparison_figures`.

:func:`write_report` writes ``REPORT.md``, ``episodes.csv.gz``, ``summary.csv``, ``comparisons.csv`` (learned policies
in today's loop), ``steps.csv`` (the step suite, with each episode's ratio to the physical bound) and ``figures/``
for the :class:`~ehss_gym.evaluation.harness.Results` of :func:`ehss_gym.evaluation.evaluate`.
"""

from __future__ import annotations

import csv
import gzip
import io
import math
import os
import time
from collections.abc import Sequence

from ehss_gym._version import __version__
from ehss_gym.core.rig import TABLE_I
from ehss_gym.core.unmodelled import DATASHEET_RANGES
from ehss_gym.envs import EnvConfig
from ehss_gym.evaluation.harness import Results
from ehss_gym.evaluation.scoring import (
    ABSOLUTE_LEVELS,
    CLASSES,
    FIGURE_SUITES,
    METRIC_KEYS,
    METRICS,
    PHYSICAL_FLOORS,
    RATE_KEYS,
    RATIO_KEYS,
    SATURATION_GATE,
    STEP_KEYS,
    Floors,
    is_earlier_loop,
    physical_floors,
)
from ehss_gym.evaluation.specs import REFERENCE_POLICY
from ehss_gym.evaluation.suites import (
    ROBUST_SEED_START,
    STEP_SECONDS,
    STEP_TIME,
    SUITES,
    SWEEP_MISMATCH_FRICTION,
    SWEEP_WINDOW,
    TASKS,
    UNITS,
    UNMODELLED_SEED_START,
)
from ehss_gym.infra.fmt import fmt_cell
from ehss_gym.infra.util import atomic_write, atomic_write_text
from ehss_gym.study.bound_table import case, kept_step_bound, prefetch

from .comparison_figures import FIGURE_KINDS, make_figures
from .render import render

DEFAULT_OUT = os.path.join("reports", "comparison")
TEMPLATE = "comparison.md.j2"
EPISODE_COLUMNS = (("suite", "task", "policy", "run", "episode", "sweep", "level", "scenario_seed", "t_end", "noisy")
                   + RATIO_KEYS + METRIC_KEYS + ("su_iae",) + STEP_KEYS
                   + ("peak_u", "tv_u", "divergence_reason", "t_diverged", "t_lost_track", "n_clipped", "t_tracking",
                      "t_disturbance"))
STEP_COLUMNS = ("task", "policy", "run", "amplitude", "step_rise_time", "step_overshoot", "step_settling_time",
                "iae_r", "iae_bound", "bound_ratio", "diverged", "lost_track", "earlier_loop")


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


# ---------------------------------------------------------------------------------------------------
# Figures with their CIs, gates


def ci_cell(d: dict, key: str) -> str:
    """A figure with its 95 % CI over episodes (and over seeds and episodes, "both", with several runs): "G [lo, hi]";
    "-" where the class is absent."""
    v = d.get(key, math.nan)
    if not math.isfinite(v):
        return "-"
    lo, hi = (d.get(f"{key}_lo_both"), d.get(f"{key}_hi_both")) if f"{key}_lo_both" in d else \
        (d.get(f"{key}_lo"), d.get(f"{key}_hi"))
    return f"{fmt(v)} [{fmt(lo)}, {fmt(hi)}]"


def gate_cell(d: dict) -> str:
    """The failure gate of a summary row: "pass", or what failed."""
    if not d["failed"]:
        return "pass"
    parts = []
    if d["n_failed"]:
        parts.append(f"{d['n_failed']} failed episode(s)")
    if d["saturation"] > SATURATION_GATE:
        parts.append(f"saturation {d['saturation']:.0%}")
    return "FAILED: " + ", ".join(parts)


def _block(res: Results, suite: str, task: str) -> list[dict]:
    return [d for d in res.summary if d["suite"] == suite and d["task"] == task]


def headline_rows(block: list[dict]) -> list[list]:
    """The first screen's table of one (suite, task): rank, policy, overall and class figures with CIs, gate
    (today's laws only, in rank order)."""
    return [[d["rank"], d["policy"], ci_cell(d, "figure")] + [ci_cell(d, c) for c in CLASSES] + [gate_cell(d)]
            for d in block if not d["earlier_loop"]]


def suite_line(block: list[dict]) -> str:
    """One line on a suite and task: the ranking with overall figures, failures marked."""
    parts = []
    for d in block:
        if d["earlier_loop"]:
            continue
        tag = " (FAILED)" if d["failed"] else ""
        parts.append(f"{d['rank']}. {d['policy']} {fmt(d['figure'])}{tag}")
    return "; ".join(parts)


def detail_rows(block: list[dict]) -> list[list]:
    """The detail table of one (suite, task): IQM, PoI and the raw class metrics of every policy (ranked first)."""
    rows = []
    for d in block:
        poi = "-" if math.isnan(d["poi_vs_best_clf"]) else \
            f"{d['poi_vs_best_clf']:.2f} [{d['poi_lo']:.2f}, {d['poi_hi']:.2f}]"
        iqm = f"{fmt(d['figure_iqm'])} [{fmt(d['figure_iqm_lo'])}, {fmt(d['figure_iqm_hi'])}]"
        rows.append([d["rank"] or "earlier loop", d["policy"], iqm, poi, fmt(d["trk_rmse"]), fmt(d["dst_peak"]),
                     fmt(d["tv_u_rate"]), fmt(d["rms_u"]), fmt(d["su_rmse"]), fmt(d["saturation"]),
                     f"{d['divergence_rate']:.0%}", f"{d['lost_track_rate']:.0%}", f"{d['n_used']}/{d['n_episodes']}"])
    return rows


def _detail_blocks(res: Results) -> list[dict]:
    """One detail block per (suite, task) that ran (figure suites)."""
    out = []
    for suite in FIGURE_SUITES:
        for task in TASKS:
            block = _block(res, suite, task)
            if block:
                out.append({"suite": suite, "task": task, "unit": UNITS[task], "n_episodes": block[0]["n_episodes"],
                            "best_clf": block[0]["best_clf"], "headline": headline_rows(block),
                            "rows": detail_rows(block)})
    return out


def absolute_table(block: list[dict], task: str, floors: Floors = PHYSICAL_FLOORS) -> tuple[list[str], list[list]]:
    """(header, rows) of the absolute levels beside the first screen's ratios (:func:`ehss_gym.evaluation.scoring.
    absolute_levels`: medians over the episodes), each header with its unit and the ruler's floor; today's laws, in
    rank order."""
    u, e = UNITS[task], floors.error[task]
    hdr = [f"tracking RMSE [{u}] (floor {fmt(e)})", f"disturbance peak [{u}] (floor {fmt(e)})",
           f"TV, noise-free [mA/s] (floor {fmt(floors.tv)})", f"TV, noisy [mA/s] (floor {fmt(floors.tv)})",
           f"RMS current [mA] (floor {fmt(floors.current)})"]
    keys = [k for k, _, _ in ABSOLUTE_LEVELS]
    return hdr, [[d["policy"]] + [fmt(d.get(k)) for k in keys] for d in block if not d["earlier_loop"]]


def _first_screen(res: Results) -> dict:
    """The first screen: per task the held-out table with its absolute levels, then one line per other suite and
    task."""
    main = []
    for t in TASKS:
        if b := _block(res, "heldout", t):
            hdr, rows = absolute_table(b, t, physical_floors(res.cfg.rig))
            main.append({"task": t, "rows": headline_rows(b), "n": b[0]["n_episodes"], "abs_headers": hdr,
                         "abs_rows": rows})
    lines = [{"suite": s, "task": t, "line": suite_line(_block(res, s, t))}
             for s in FIGURE_SUITES if s != "heldout" for t in TASKS if _block(res, s, t)]
    return {"main": main, "lines": lines}


def earlier_rows(res: Results) -> list[list]:
    """The learned policies recorded in an earlier loop: their figures, not ranked against today's laws."""
    return [[d["suite"], d["task"], d["policy"], ci_cell(d, "figure")] + [ci_cell(d, c) for c in CLASSES]
            + [gate_cell(d)] for d in res.summary if d["earlier_loop"]]


def _comparison_rows(res: Results) -> list[list]:
    """Rows of the learned-against-scripted table (today's loop; ratios [-])."""
    return [[c["suite"], c["task"], c["policy"], c["n_runs"], c["best_clf"],
             f"{c['improvement']:+.1%} [{c['improvement_lo']:+.1%}, {c['improvement_hi']:+.1%}]",
             f"{c['poi']:.2f} [{c['poi_lo']:.2f}, {c['poi_hi']:.2f}]", c["base_law"], _over_base(c)]
            + [fmt(c[f"{cls}_ratio"]) for cls in CLASSES] for c in res.comparisons]


def _over_base(c: dict) -> str:
    """A comparison's overall figure over its base law's with its CI (results made before the column: blank)."""
    if not math.isfinite(c.get("ratio_to_base", math.nan)):
        return ""
    return f"{fmt(c['ratio_to_base'])} [{fmt(c['ratio_to_base_lo'])}, {fmt(c['ratio_to_base_hi'])}]"


# ---------------------------------------------------------------------------------------------------
# The step suite and its physical bound


def bound_function():
    """:func:`ehss_gym.study.bound_table.kept_step_bound`, the bound the step table's ratios take (the table shipped
    with the package, or computed once per case; tests replace it)."""
    return kept_step_bound


def _step_plants(res: Results) -> dict:
    """(task, amplitude) -> the plant of that step-suite episode (the true plant the bound is taken on)."""
    return {(ep.task, ep.level): ep.physical["plant"] for ep in getattr(res, "episodes", ()) if ep.suite == "step"}


def _rig(res: Results):
    """The rig the evaluation ran on (Table I for results made without one)."""
    cfg = getattr(res, "cfg", None)
    return getattr(cfg, "rig", TABLE_I) if cfg is not None else TABLE_I


def _step_case(task: str, amplitude: float, plant=None, rig=TABLE_I) -> dict:
    """The bound's case of one step of the suite: its plant (default: the rig's), at the env's current limit for the
    task on that rig."""
    limit = EnvConfig.from_kwargs({"task": task, "plant": rig}).current_limit
    return case(task, amplitude, t_step=STEP_TIME, t_end=STEP_SECONDS[task], current_limit=limit,
                plant=rig.plant if plant is None else plant)


def prefetch_bounds(res: Results, executor=None, progress: bool = False) -> int:
    """Compute the step suite's bounds that are neither shipped nor kept, as jobs of ``executor`` (in parallel, and
    kept in its store: :func:`ehss_gym.study.bound_table.prefetch`); returns how many were computed or read from the
    store. With the default bound only (a replaced :func:`bound_function` computes its own)."""
    if bound_function() is not kept_step_bound:
        return 0
    plants = _step_plants(res)
    keys = dict.fromkeys((r["task"], r["level"]) for r in res.rows if r["suite"] == "step")
    return prefetch([_step_case(t, a, plants.get((t, a)), _rig(res)) for t, a in keys], executor, progress)


def step_rows(res: Results, bound=None, notes: list | None = None) -> list[dict]:
    """One row per step-suite episode and run: its step metrics, ``iae_r`` [output unit * s] and, with ``bound``
    (:func:`bound_function`), the least IAE of y - r any policy can reach under the current limit
    (``iae_bound``) and ``bound_ratio`` = iae_r / iae_bound. A step the bound refuses (its ValueError, e.g. a
    velocity the current limit cannot hold) gets NaN and its reason appended to ``notes``."""
    cache: dict = {}
    out = []
    specs = {sp.name: sp for sp in res.specs}
    plants = _step_plants(res)
    for r in res.rows:
        if r["suite"] != "step":
            continue
        d = {k: r[k] for k in ("task", "policy", "run", "iae_r", "diverged", "lost_track") + STEP_KEYS}
        d["amplitude"] = r["level"]
        d["earlier_loop"] = is_earlier_loop(specs[r["policy"]], r["task"]) if r["policy"] in specs else False
        if bound is not None:
            key = (r["task"], r["level"])
            if key not in cache:
                cache[key] = _bound_of(bound, r["task"], r["level"], notes, plants.get(key), _rig(res))
            d["iae_bound"] = cache[key]
            d["bound_ratio"] = r["iae_r"] / cache[key] if cache[key] > 0 else math.nan
        out.append(d)
    return out


def _bound_of(bound, task: str, amplitude: float, notes: list | None, plant=None,
              rig=TABLE_I) -> float:
    """The bound's IAE [output unit * s] of one step of the suite on ``plant`` (default: the rig's) under the rig's
    current limit, NaN (and a note) where the bound refuses it."""
    c = _step_case(task, amplitude, plant, rig)
    try:
        return float(bound(task, amplitude, t_step=c["t_step"], t_end=c["t_end"], plant=c["plant"],
                           current_limit=c["current_limit"]).iae_bound)
    except ValueError as exc:
        if notes is not None:
            notes.append(f"{task}, step {amplitude:+g}: no physical bound ({exc})")
        return math.nan


def step_table(rows: list[dict], with_bound: bool) -> list[list]:
    """The step suite's table: per task, policy and amplitude the metrics (means over runs)."""
    groups: dict = {}
    for d in rows:
        groups.setdefault((d["task"], d["policy"], d["amplitude"]), []).append(d)
    out = []
    for (task, pol, amp), ds in groups.items():
        keys = STEP_KEYS + ("iae_r",) + (("bound_ratio",) if with_bound else ())
        mean = {k: sum(x[k] for x in ds) / len(ds) for k in keys}
        label = pol + (" (earlier loop)" if ds[0].get("earlier_loop") else "")
        row = [task, label, f"{amp:+g}", fmt(mean["step_rise_time"]), fmt(mean["step_overshoot"]),
               fmt(mean["step_settling_time"]), fmt(mean["iae_r"])]
        if with_bound:
            row += [fmt(ds[0]["iae_bound"]), fmt(mean["bound_ratio"])]
        out.append(row + ["yes" if any(x["diverged"] or x["lost_track"] for x in ds) else "no"])
    return out


def step_lines(rows: list[dict], with_bound: bool) -> list[dict]:
    """The first screen's line per task: each policy's geometric-mean ratio to the bound (or its mean IAE)."""
    out = []
    for task in TASKS:
        sel = [d for d in rows if d["task"] == task]
        if not sel:
            continue
        parts = []
        for pol in dict.fromkeys(d["policy"] for d in sel):
            ds = [d for d in sel if d["policy"] == pol]
            tag = " (earlier loop)" if ds[0].get("earlier_loop") else ""
            if with_bound:
                v = [d["bound_ratio"] for d in ds if d["bound_ratio"] > 0 and math.isfinite(d["bound_ratio"])]
                g = math.exp(sum(math.log(x) for x in v) / len(v)) if v else math.nan
                parts.append(f"{pol}{tag} {fmt(g)}x the bound")
            else:
                parts.append(f"{pol}{tag} IAE {fmt(sum(d['iae_r'] for d in ds) / len(ds))} {UNITS[task]}*s")
        out.append({"task": task, "line": "; ".join(parts)})
    return out


# ---------------------------------------------------------------------------------------------------
# Settings (at the end of the report)


def _policy_rows(res: Results) -> list[list]:
    """Rows of the policies table: name, kind, runs, tasks, env settings, source."""
    out = []
    for s in res.specs:
        kw = ", ".join(f"{k}={v!r}" for k, v in sorted(s.env_kwargs.items())) or "defaults"
        out.append([s.name, s.kind, len(s.runs), ", ".join(s.tasks), _md(kw), _md(s.source)])
    return out


def _env_rows(res: Results) -> list[list]:
    """Rows of the env-defaults table, one per evaluated task (frequencies [Hz], currents [mA], periods [s])."""
    out = []
    for task in res.cfg.tasks:
        c = EnvConfig.from_kwargs({"task": task, **res.cfg.env_kwargs()})
        out.append([task, f"{c.fr:g}", f"{c.sigma:g}", f"{c.smoothing:g}", c.current_limit, f"{c.control_period:g}",
                    c.substeps, c.agent_period, c.estimator, f"{c.layer_gain:g}", c.bumpless, f"{c.ref_accel:g}"])
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


def report_context(res: Results, figs: dict, steps: list[dict], with_bound: bool) -> dict:
    """Everything templates/comparison.md.j2 shows: settings, numbers and table rows (as cell strings).

    Args:
        res: the evaluation's results.
        figs: what :func:`~ehss_gym.reporting.comparison_figures.make_figures` returned (kind -> (path, suite or
            task) pairs; the template words the captions).
        steps: :func:`step_rows`.
        with_bound: the step rows carry the physical bound.
    """
    metric_header, metric_rows = _metric_table(res)
    return {
        "command": res.command, "version": __version__, "n_episodes": len(res.rows), "workers": res.workers,
        "plant": res.cfg.rig.text(), "plant_given": res.cfg.plant is not None,
        "law_settings": None if res.cfg.law_settings is None else res.cfg.law_settings.describe(),
        "wall_time": res.wall_time, "timings": ", ".join(f"{k} {v:.1f} s" for k, v in res.timings.items()),
        "learned": any(s.learned for s in res.specs), "notes": list(res.notes), "cfg": res.cfg,
        "policy_rows": _policy_rows(res), "env_rows": _env_rows(res), "classes": CLASSES,
        "reference": REFERENCE_POLICY, "floors": physical_floors(res.cfg.rig).rows(),
        "saturation_gate": SATURATION_GATE,
        "robust_seed_start": ROBUST_SEED_START, "sweep_window": SWEEP_WINDOW,
        "unmodelled_seed_start": UNMODELLED_SEED_START, "unmodelled_ranges": DATASHEET_RANGES,
        "rated_current": res.cfg.rig.rated_current,
        "mismatch_friction": SWEEP_MISMATCH_FRICTION, "step_time": STEP_TIME, "step_seconds": STEP_SECONDS,
        "metric_rows": [[f"{_md(label)} (`{key}`)", unit, _md(text)] for key, label, unit, text in METRICS],
        "first": _first_screen(res), "blocks": _detail_blocks(res), "earlier_rows": earlier_rows(res),
        "metric_header": metric_header, "all_metric_rows": metric_rows,
        "figs": {k: list(figs.get(k, [])) for k in FIGURE_KINDS}, "comparison_rows": _comparison_rows(res),
        "step_rows": step_table(steps, with_bound), "step_lines": step_lines(steps, with_bound),
        "with_bound": with_bound, "suites": SUITES,
    }


def report_text(res: Results, figs: dict, steps: list[dict] | None = None, with_bound: bool = False,
                bound_notes: Sequence[str] = ()) -> str:
    """The markdown report (templates/comparison.md.j2 filled with :func:`report_context`)."""
    return render(TEMPLATE, **report_context(res, figs, steps or [], with_bound), bound_notes=list(bound_notes))


def _plant_column(res: Results):
    """(rows, columns) -> (rows, columns) with a ``plant`` column (the rig's label: name, file, hash of its values)
    when the evaluation was given a plant; unchanged otherwise (no plant given: the columns of Table I's CSVs)."""
    if res.cfg.plant is None:
        return lambda rows, columns: (rows, columns)
    label = res.cfg.rig.label
    return lambda rows, columns: ([{**r, "plant": label} for r in rows], ["plant", *columns])


EPISODES_FILE = "episodes.csv.gz"  # one row per episode: gzip keeps the full-evaluation table a few MB


def write_episodes(path: str, text: str) -> None:
    """Write the episode table ``text`` gzip-compressed to ``path``, byte for byte the same for the same text (no
    time stamp or file name in the gzip header: the local backend and a Ray cluster write the same bytes); a plain
    ``episodes.csv`` that an earlier release wrote beside it is removed, so the folder holds one episode table."""
    atomic_write(path, lambda f: f.write(gzip.compress(text.encode(), mtime=0)))
    old = os.path.join(os.path.dirname(path), "episodes.csv")
    if os.path.isfile(old):
        os.remove(old)


def read_episodes(folder: str) -> list[dict]:
    """The episode rows (strings, as :class:`csv.DictReader` reads them) of the report in ``folder``."""
    with gzip.open(os.path.join(folder, EPISODES_FILE), "rt", newline="") as f:
        return list(csv.DictReader(f))


def write_report(res: Results, out: str) -> str:
    """Write REPORT.md, episodes.csv.gz, summary.csv, comparisons.csv, steps.csv and figures/ under ``out``; returns
    REPORT.md.

    Every file is written atomically; REPORT.md last, so an interrupted run leaves the previous report. The wall
    time [s] of each phase is added to ``res.timings``: ``bounds`` (the step suite's physical bounds, added to what
    :func:`prefetch_bounds` took), ``figures`` and ``report`` (tables, CSVs and the text); ``res.wall_time`` becomes
    the time from ``res.started`` to the report.
    """
    t0 = time.perf_counter()
    os.makedirs(os.path.join(out, "figures"), exist_ok=True)
    tag = _plant_column(res)
    write_episodes(os.path.join(out, EPISODES_FILE), csv_text(*tag(res.rows, EPISODE_COLUMNS)))
    atomic_write_text(os.path.join(out, "summary.csv"), csv_text(*tag(res.summary, _columns(res.summary))))
    if res.comparisons:
        atomic_write_text(os.path.join(out, "comparisons.csv"),
                          csv_text(*tag(res.comparisons, _columns(res.comparisons))))
    bound = bound_function() if any(r["suite"] == "step" for r in res.rows) else None
    bound_notes: list = []
    t1 = time.perf_counter()
    steps = step_rows(res, bound, bound_notes)
    t2 = time.perf_counter()
    if bound is not None:
        res.timings["bounds"] = res.timings.get("bounds", 0.0) + (t2 - t1)
    if steps:
        atomic_write_text(os.path.join(out, "steps.csv"), csv_text(*tag(steps, STEP_COLUMNS)))
    t3 = time.perf_counter()
    figs = make_figures(res, os.path.join(out, "figures"))
    t4 = time.perf_counter()
    res.timings["figures"] = t4 - t3
    res.timings["report"] = (t1 - t0) + (t3 - t2)  # the tables and CSVs; rendering the text takes milliseconds
    if math.isfinite(res.started):
        res.wall_time = t4 - res.started
    text = report_text(res, figs, steps, bound is not None, bound_notes)
    path = os.path.join(out, "REPORT.md")
    atomic_write_text(path, text)
    return path


__all__ = ["DEFAULT_OUT", "EPISODE_COLUMNS", "EPISODES_FILE", "write_episodes", "read_episodes",
           "STEP_COLUMNS", "fmt", "csv_text", "ci_cell", "gate_cell",
           "step_rows", "prefetch_bounds", "report_context", "report_text", "write_report"]
