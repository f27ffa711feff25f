"""The reproduction study's report: figures, CSV tables and numbers computed here, prose in templates/paper.md.j2.

:func:`write_report` writes ``REPORT.md``, ``figures/``, ``data/`` and ``recommended_defaults.json``.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import resource
import time
from collections.abc import Sequence

import numba as nb

from ehss_gym._version import __version__
from ehss_gym.core.params import PlantParams
from ehss_gym.envs import EnvConfig
from ehss_gym.infra.fmt import fmt_axis, md_table
from ehss_gym.infra.fmt import fmt_num as _f
from ehss_gym.infra.util import atomic_write, atomic_write_text
from ehss_gym.study.claims import (
    CLAIMS,
    HELDOUT,
    VERDICTS,
    claims_on_cell,
    context_verdicts,
    judge_claims,
    runs_of_records,
)
from ehss_gym.study.config import (
    C4_TOL,
    CHATTER_STRONG,
    CHATTER_WINDOW,
    CLAIM_CONFIGS,
    CLAIM_PERIOD,
    CONFIG_FIGS,
    CONFIGS,
    EDGE_TOL,
    G_NOMINAL,
    MATTERS,
    NS,
    OSC_PAPER,
    OSC_RATIO,
    REC_ABS,
    SAT_MATTERS,
    SLIGHT_TOL,
    SUPPRESS,
    TRACK_TOL,
)
from ehss_gym.study.records import Record
from ehss_gym.study.rules import attraction_bounds, lost_table
from ehss_gym.study.stages import Study

from . import paper_facts as facts
from .paper_figures import (
    plot_divergence,
    plot_lost_track,
    plot_paper_set,
    plot_relay,
    plot_smoothing,
    plot_sweep_maps,
    run_plot_jobs,
)
from .render import render

METRIC_COLS = (("rmse", "RMSE"), ("rmse_quiet", "RMSE quiet"), ("max_abs_e_friction", "max abs e friction"),
               ("recovery_on", "rec. on [s]"), ("recovery_off", "rec. off [s]"), ("tv_u_rate", "TV rate [mA/s]"),
               ("peak_u", "peak abs u cmd [mA]"), ("peak_u_applied", "peak abs u applied [mA]"),
               ("saturation", "saturation"))
SET_TITLES = {
    "P0": "the law as printed: sigma = 1, no current limit (the paper's)",
    "P1": "sigma = 1 with a 10 mA limit at the core's default 10 kHz",
    "P2": "sigma = 1 with a 10 mA limit at 100 kHz",
    "P3": "normalised CLF (recommended sigma, period, substeps, limit), plain law w = 0",
    "P4": "P3 plus this study's chosen smoothing (its recommendation; the env's defaults have moved on since, "
          "docs/ENV.md)",
    "P1_old": "P1 with the first implementation's biased ZOH filters",
    "P3_old": "the first implementation's P3 (its recommended settings) with its ZOH filters",
}
CLAIM_SETS = ("P0", "P1", "P2", "P3")
OLD_NEW = (("P1", "P1_old"), ("P3", "P3_old"))
FINAL_ROWS = (("old", "the first implementation's defaults, its ZOH filters"),
              ("fixed", "the first implementation's defaults, corrected filters"),
              ("new", "this study's recommendation, corrected filters"))


def csv_write(path: str, records: Sequence[Record]) -> None:
    """Settings, metrics and features of runs as one CSV table."""
    pkeys = ["group", "task", "fr", "n", "sigma", "smoothing", "limit", "h", "substeps", "t_end", "estimator_hz",
             "estimator", "law", "layer_gain", "observer_hz", "bumpless", "ref_accel", "pressure_domain", "noisy"]
    mkeys = ["diverged", "t_diverged", "divergence_reason", "rmse", "rmse_nominal", "rmse_quiet", "iae", "max_abs_e",
             "max_abs_e_friction", "recovery_on", "recovery_off", "tv_u", "tv_u_rate", "peak_u", "peak_u_applied",
             "rms_u", "saturation", "v_decrease", "steps", "trk_rmse", "trk_iae", "dst_peak", "dst_iae"]
    fkeys = sorted({k for r in records for k in r.features})
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(pkeys + mkeys + fkeys)
    for r in records:
        w.writerow([r.group] + [r.params.get(k) for k in pkeys[1:]] + [r.metrics.get(k) for k in mkeys]
                   + [r.features.get(k) for k in fkeys])
    atomic_write(path, lambda f: f.write(buf.getvalue()), mode="w")


def metric_row(r: Record) -> list:
    m = r.metrics
    cells = [f"{r.params['task']} {r.params['fr']:g} Hz", str(r.params["n"])]
    cells.append(f"**diverged** at {m['t_diverged']:.4g} s ({m['divergence_reason']})" if m["diverged"] else "no")
    cells += [_f(m[k]) if k != "saturation" else f"{m[k]:.2%}" for k, _ in METRIC_COLS]
    return cells


def set_desc(recs: Sequence[Record]) -> str:
    p = recs[0].params
    lim = "none" if p["limit"] is None else f"{p['limit']:g} mA"
    sig = sorted({(r.params["task"], r.params["sigma"]) for r in recs})
    sg = ", ".join(f"{t} {s:g}" for t, s in sig) if len({s for _, s in sig}) > 1 else f"{sig[0][1]:g}"
    return (f"sigma = {sg}; h = {p['h']:g} s; {p['substeps']} RK4 substeps; current limit {lim}; "
            f"smoothing w = {p['smoothing']:g}; filters {p['estimator']}; {p['t_end']:g} s")


def runs_by_set(st: Study, key: str) -> dict:
    """(task, f_r, n) -> record of one paper set."""
    return {(r.params["task"], r.params["fr"], r.params["n"]): r for r in st.group(key)}


def rec_of(st: Study, group: str, **params):
    """The first record of ``group`` whose params match, or None."""
    return next((r for r in st.group(group) if all(r.params.get(k) == v for k, v in params.items())), None)


# ------------------------------------------------------------------------------------------------
# Figures and data
# ------------------------------------------------------------------------------------------------

SWEEPS = (("sigma_period", "sigma", "h", "CLF scale sigma", "control period h [s]"),
          ("position_sigma_period", "sigma", "h", "CLF scale sigma", "control period h [s]"),
          ("sigma_limit", "sigma", "limit", "CLF scale sigma", "current limit [mA]"),
          ("sigma_fr", "sigma", "fr", "CLF scale sigma", "f_r [Hz]"),
          ("position_sigma", "sigma", "task", "CLF scale sigma", ""))


def _sweep_desc(st: Study, name: str) -> str:
    cfg, rec = st.cfg, st.rec
    tiny = f"; * = {cfg.tiny_t_end:g} s runs" if cfg.tiny_periods else ""
    return {"sigma_period": "velocity, f_r = 100 Hz, limit 10 mA, plain law" + tiny,
            "position_sigma_period": "position, f_r = 60 Hz, limit 10 mA, plain law, n = 2",
            "sigma_limit": f"velocity, f_r = {rec['fr_velocity']:g} Hz, h = {rec['h']:g} s, plain law",
            "sigma_fr": f"velocity, limit 10 mA, h = {rec['h']:g} s, plain law",
            "position_sigma": f"position, f_r = 60 Hz, limit 10 mA, h = {rec['h']:g} s, plain law"}[name]


def figure_jobs(st: Study, figs: str, cmd: str) -> list:
    """(function, args) of every figure."""
    cfg, rec = st.cfg, st.rec
    jobs = []
    for key, title in SET_TITLES.items():
        recs = st.group(key)
        if not recs:
            continue
        if key == "P0":
            jobs.append((plot_divergence, (recs, os.path.join(figs, "paper_P0_divergence.png"), cmd)))
            continue
        for task, fr in CONFIGS:
            jobs.append((plot_paper_set, (recs, task, fr, os.path.join(figs, f"paper_{key}_{task}_{fr:g}.png"),
                                          f"{CONFIG_FIGS[(task, fr)]} ({task}, f_r = {fr:g} Hz), set {key}: "
                                          f"{title}\n{set_desc(recs)}", cmd)))
    runs = designated_runs(st)
    for c, (task, _, _) in CLAIM_CONFIGS.items():
        recs = [r for (cc, _), r in runs.items() if cc == c]
        if recs:
            jobs.append((plot_paper_set, (recs, task, None, os.path.join(figs, f"claims_{c.replace(' ', '_')}.png"),
                                          f"Claims, designated configuration '{c}': {_config_short(c)}", cmd)))
    fric = (f"{cfg.sweep_t_end:g} s runs, friction {cfg.sweep_friction[0][0]:g} N m on "
            f"[{cfg.sweep_friction[0][1]:.3f}, {cfg.sweep_friction[0][2]:.3f}) s")
    for name, row, col, rl, cl in SWEEPS:
        if st.group(name):
            jobs.append((plot_sweep_maps, (st.group(name), row, col, os.path.join(figs, f"sweep_{name}.png"),
                                           f"Sweep {name}: {_sweep_desc(st, name)}; {fric}", cmd, rl, cl,
                                           cfg.tiny_periods if name == "sigma_period" else ())))
    lim_recs = [r for g in ("sigma_period", "sigma_limit", "sigma_fr") for r in st.group(g)
                if r.params["limit"] is not None]
    jobs.append((plot_relay, (lim_recs, os.path.join(figs, "relay_index.png"), cmd)))
    jobs.append((plot_smoothing, (st.group("smoothing"), st.group("smoothing_coarse"), st.group("snippet"),
                                  os.path.join(figs, "smoothing.png"), cmd)))
    h_old = cfg.old("velocity")["control_period"]
    jobs.append((plot_lost_track, (rec["dist_table"], rec["h"],
                                   lost_table(st.group("map_old"), ("h", "fr", "sigma"), cfg.lost_rms), h_old,
                                   lost_table(st.group("map_smoothing"), ("fr", "smoothing"), cfg.lost_rms),
                                   lost_table(st.group("map_limit"), ("fr", "limit"), cfg.lost_rms),
                                   attraction_bounds(st.group("roa"), cfg.lost_rms),
                                   os.path.join(figs, "lost_track.png"), cmd)))
    return jobs


DATA_GROUPS = ("sigma_period", "position_sigma_period", "sigma_limit", "sigma_fr", "position_sigma", "smoothing",
               "smoothing_position", "smoothing_coarse", "substeps", "divergence", "probe", "position_probe", "roa")


def write_data(st: Study, data: str) -> None:
    """Every group of runs as CSV: sweeps, probes, paper runs, and the randomised-scenario checks."""
    for g in DATA_GROUPS:
        if st.group(g):
            csv_write(os.path.join(data, f"{'sweep_' if g in dict.fromkeys(s[0] for s in SWEEPS) else ''}{g}.csv"),
                      st.group(g))
    csv_write(os.path.join(data, "paper_runs.csv"), [r for k in SET_TITLES for r in st.group(k)])
    if st.group("claims"):
        csv_write(os.path.join(data, "claims_runs.csv"), st.group("claims") + st.group("claims_heldout"))
    dist = [r for g in sorted(st.records) if g.startswith(("distribution", "map_", "final_")) for r in st.group(g)]
    csv_write(os.path.join(data, "randomised_scenarios.csv"), dist)


# ------------------------------------------------------------------------------------------------
# Claims
# ------------------------------------------------------------------------------------------------


def designated_runs(st: Study) -> dict:
    """(claim configuration, n) -> the designated run (group "claims")."""
    return runs_of_records(st.group("claims"))


def heldout_by_task(st: Study) -> dict:
    """task -> n -> the held-out episodes' metrics (group "claims_heldout", in episode order)."""
    out: dict = {}
    for r in st.group("claims_heldout"):
        out.setdefault(r.params["task"], {}).setdefault(r.params["n"], []).append(r.metrics)
    return out


def _law_text(p: dict) -> str:
    return (f"sigma {p['sigma']:g}, w {p['smoothing']:g}, layer gain {p['layer_gain']:g}, f_r {p['fr']:g} Hz, "
            f"{p['law']}, estimator {p['estimator']}")


def claim_config_rows(st: Study) -> list:
    """One row per designated run: configuration, n and its settings."""
    rows = []
    for (c, n), r in sorted(designated_runs(st).items(), key=lambda kv: (list(CLAIM_CONFIGS).index(kv[0][0]),
                                                                          kv[0][1])):
        p = r.params
        rows.append([c, n, fmt_axis(p["limit"]), f"{p['h']:g}", _law_text(p),
                     f"{p['t_end']:g} s, paper's start" if not p["bumpless"] else f"{p['t_end']:g} s"])
    held = st.group("claims_heldout")
    for task in dict.fromkeys(r.params["task"] for r in held):
        for n in NS:
            rs = [r for r in held if r.params["task"] == task and r.params["n"] == n]
            if rs:
                p = rs[0].params
                rows.append([f"{HELDOUT} ({task})", n, fmt_axis(p["limit"]), f"{p['h']:g}", _law_text(p),
                             f"{len(rs)} episodes of {p['t_end']:g} s, bumpless start"])
    return rows


def _context_text(cells: list) -> str:
    if not cells:
        return "no sweep cell holds its runs"
    k = {v: sum(r.verdict == v for _, r in cells) for v in VERDICTS}
    return f"{k[VERDICTS[0]]} reproduced, {k[VERDICTS[1]]} partly of {len(cells)} sweep cells"


def _config_short(c: str) -> str:
    if c == HELDOUT:
        return f"{HELDOUT}, both tasks, env defaults per n"
    task, fr, lim = CLAIM_CONFIGS[c]
    frs = "the env's per n" if fr is None else f"{fr:g} Hz"
    lims = "no limit" if lim is None else f"{lim:g} mA"
    return f"{task}, f_r {frs}, {lims}, h {CLAIM_PERIOD:g} s, paper's run, env defaults per n"


def claims_context(st: Study, data: str) -> dict:
    """The verdict table (rule, configuration, numbers, verdict, sweep context), the verdict per paper set, old
    against new, and data/claims.csv."""
    verdicts = judge_claims(designated_runs(st), heldout_by_task(st))
    set_res = {k: claims_on_cell(runs_of_records(st.group(k))) for k in CLAIM_SETS if st.group(k)}
    old_sets = {k: claims_on_cell(runs_of_records(st.group(k))) for pair in OLD_NEW for k in pair if st.group(k)}
    sweep_res = context_verdicts(st.records)
    rows, detail = [], []
    for cid, c in CLAIMS.items():
        res = verdicts[cid]
        fig = (f"[fig](figures/claims_{c.config.replace(' ', '_')}.png)" if c.config != HELDOUT else "")
        rows.append([cid, c.paper, c.rule, _config_short(c.config), res.evidence, f"**{res.verdict}**",
                     _context_text(sweep_res.get(cid, [])), fig])
        detail.append([cid] + [set_res[k][cid].verdict if cid in set_res[k] else "-" for k in set_res])
    old_new = [[cid] + [f"{old_sets[old][cid].verdict} -> {old_sets[new][cid].verdict}"
                        if cid in old_sets[old] and cid in old_sets[new] else "-"
                        for new, old in OLD_NEW if new in old_sets and old in old_sets] for cid in CLAIMS]
    changed = [(cid, new, old_sets[old][cid], old_sets[new][cid]) for cid in CLAIMS for new, old in OLD_NEW
               if new in old_sets and old in old_sets and cid in old_sets[old] and cid in old_sets[new]
               and old_sets[old][cid].verdict != old_sets[new][cid].verdict]

    def write(f):
        w = csv.writer(f)
        w.writerow(["claim", "where", "verdict", "evidence"])
        for cid, r in verdicts.items():
            w.writerow([cid, f"designated: {CLAIMS[cid].config}", r.verdict, r.evidence])
        for k, res in {**set_res, **old_sets}.items():
            for cid, r in res.items():
                w.writerow([cid, k, r.verdict, r.evidence])
        for cid, cells in sweep_res.items():
            for lab, r in cells:
                w.writerow([cid, lab, r.verdict, r.evidence])

    atomic_write(os.path.join(data, "claims.csv"), write, mode="w")
    return {"claims_table": md_table(["claim", "paper says", "rule", "configuration", "measured", "verdict",
                                      "context: the rule on the sweep cells", "figure"], rows),
            "claims_config": md_table(["configuration", "n", "limit [mA]", "h [s]", "law (the env's defaults for n)",
                                       "run"], claim_config_rows(st)),
            "claims_detail": md_table(["claim"] + list(set_res), detail),
            "claims_old_new": md_table(["claim"] + [f"{old} -> {new}" for new, old in OLD_NEW], old_new),
            "claims_changed": changed}


# ------------------------------------------------------------------------------------------------
# Recommended defaults and the report
# ------------------------------------------------------------------------------------------------


def recommendation_json(st: Study) -> dict:
    """The recommended env defaults, machine-readable, with the rules that chose them."""
    rec, cfg = st.rec, st.cfg
    p4 = runs_by_set(st, "P4")
    return {
        "generated_by": "ehss reproduce",
        "ehss_gym_version": __version__,
        "quick_mode": cfg.quick,
        "estimator": cfg.estimator,
        "n": 2,
        "control_period_s": rec["h"],
        "control_period_paper_s": rec["h_paper"],
        "control_period_rule_s": {"velocity": rec["h_velocity_rule"], "position": rec["h_position_rule"]},
        "substeps": rec["substeps"],
        "current_limit_mA": rec["limit"],
        "current_limit_paper_mA": rec["limit_paper"],
        "fr_hz": {"velocity": rec["fr_velocity"], "position": rec["fr_position"]},
        "sigma": {"velocity": rec["sigma_velocity"], "position": rec["sigma_position"]},
        "sigma_paper_rule": {"velocity": rec["sigma_paper"], "position": rec["sigma_position_paper"]},
        "sigma_by_n": {"velocity": {str(k): v for k, v in rec["sigma_by_n_velocity"].items()},
                       "position": {str(k): v for k, v in rec["sigma_by_n_position"].items()}},
        "smoothing": {"velocity": rec["smoothing"], "position": rec["smoothing_position"]},
        "estimator_hz": {"velocity": 1000.0, "position": 1000.0},
        "robust_rule_met": {"velocity": bool(rec["dist_rule_met"]), "position": bool(rec["pos_dist_rule_met"]),
                            "current_limit": bool(rec["dist_limit_rule_met"])},
        "lost_share": {f"{t}_{suite}_{kind}": lost_table(st.group(f"final_{t}_{suite}_{kind}"), ("task",),
                                                         cfg.lost_rms).get(t, (math.nan,))[0]
                       for t in ("velocity", "position") for suite in ("random", "heldout")
                       for kind in ("old", "fixed", "new")},
        "position_base_law_saturates": bool(rec.get("position_saturating")),
        "base_law_saturation_fraction": {f"{t}_{fr:g}Hz_n{n}": r.metrics["saturation"]
                                         for (t, fr, n), r in p4.items()},
        "rules": {
            "control_period": "per task, the largest h whose best non-saturating (<= 1 %) sigma gives a quiet RMSE "
                              "within 2x the best over all h (n = 2, 10 mA, plain law; f_r 100 Hz velocity, 60 Hz "
                              "position); the env's one period is the shorter of the two (control_period_paper_s), "
                              "then the shortest h >= it at which some (f_r, sigma) loses track on <= "
                              f"{cfg.max_lost:.0%} of {cfg.dist_episodes} randomised training scenarios (velocity)",
            "fr_sigma": "at that period, among f_r in the candidates and every sigma the first rule admits, the cell "
                        "with the lowest median RMSE over the randomised scenarios among those losing track on <= "
                        f"{cfg.max_lost:.0%}; position the same at the env's period (if none passes, the lowest "
                        "lost share and robust_rule_met = false)",
            "substeps": "smallest substeps whose quiet RMSE and friction peak are within 2 % of 8 substeps' for "
                        "n = 2, 4, 6",
            "current_limit": "smallest limit with saturation <= 1 %, recovery after both friction edges and quiet "
                             "RMSE within 25 % of the unlimited law's (n = 2): current_limit_paper_mA; then the "
                             "smallest limit >= it (up to 10 mA) that passes the lost-track check",
            "smoothing": "width with the lowest control TV among those keeping quiet RMSE and friction peak within "
                         "10 % of the plain law's (n = 2), per task",
        },
    }


def env_agreement(st: Study) -> tuple[list, list]:
    """(settings the env's defaults restate from this study's recommendation, settings where they differ), as
    "name (task)" labels, read from EnvConfig."""
    rec = st.rec
    same, diff = [], []
    for task in ("velocity", "position"):
        env = EnvConfig.from_kwargs({"task": task})
        ours = {"control_period": rec["h"], "substeps": rec["substeps"], "current_limit": rec["limit"],
                "fr": rec[f"fr_{task}"], "sigma": rec[f"sigma_{task}"],
                "smoothing": rec["smoothing" if task == "velocity" else "smoothing_position"],
                "estimator": st.cfg.estimator}
        for key, v in ours.items():
            (same if getattr(env, key) == v else diff).append(f"{key} ({task})")
    return same, diff


def _cpu_seconds() -> float:
    """CPU time of this process and its finished children (the plot workers) [s]."""
    a = resource.getrusage(resource.RUSAGE_SELF)
    b = resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime


def paper_tables(st: Study) -> dict:
    """Markdown tables of the paper sets, the sweeps' settings, substeps and limits."""
    rec = st.rec
    sets = {}
    for k in SET_TITLES:
        recs = sorted(st.group(k), key=lambda r: (CONFIGS.index((r.params["task"], r.params["fr"])), r.params["n"]))
        if recs and k != "P0":
            sets[k] = {"title": SET_TITLES[k], "desc": set_desc(recs),
                       "table": md_table(["config", "n", "diverged"] + [c for _, c in METRIC_COLS],
                                         [metric_row(r) for r in recs])}
    ssr = sorted(st.group("substeps"), key=lambda r: (r.params["n"], r.params["substeps"]))
    lim = sorted((r for r in st.group("sigma_limit") if r.params["sigma"] == rec["sigma_velocity"]
                  and r.params["n"] == 2), key=lambda r: (r.params["limit"] is not None, r.params["limit"] or 0))
    pp = sorted(st.group("position_probe"), key=lambda r: (r.params["estimator"] != st.cfg.estimator, r.params["h"],
                                                           r.params["fr"], r.params["limit"] is None))
    return {
        "set_rows": md_table(["set", "what", "settings"], [[k, SET_TITLES[k], set_desc(st.group(k))]
                                                          for k in SET_TITLES if st.group(k)]),
        "sets": sets,
        "substeps_table": md_table(["n", "sigma", "substeps", "RMSE quiet", "friction peak", "TV rate"],
                                   [[r.params["n"], f"{r.params['sigma']:g}", r.params["substeps"],
                                     _f(r.get("rmse_quiet"), ".5g"), _f(r.get("max_abs_e_friction"), ".5g"),
                                     _f(r.get("tv_u_rate"), ".4g")] for r in ssr]),
        "limit_table": md_table(["limit [mA]", "diverged", "RMSE quiet", "friction peak", "rec. on", "rec. off",
                                 "saturation"],
                                [[fmt_axis(r.params["limit"]), "yes" if r.get("diverged") else "no",
                                  _f(r.get("rmse_quiet")), _f(r.get("max_abs_e_friction")), _f(r.get("recovery_on")),
                                  _f(r.get("recovery_off")), f"{r.get('saturation'):.2%}"] for r in lim]),
        "limit_runs": {r.params["limit"]: r for r in lim},
        "position_probe_table": md_table(
            ["filters", "h [s]", "f_r [Hz]", "sigma", "limit", "diverged", "RMSE [rad]", "median abs psi/G [mA]",
             "peak abs u cmd [mA]", "TV rate [mA/s]", "saturation"],
            [[r.params["estimator"], f"{r.params['h']:g}", f"{r.params['fr']:g}", fmt_axis(r.params["sigma"]),
              fmt_axis(r.params["limit"]), f"at {r.get('t_diverged'):.3g} s" if r.get("diverged") else "no",
              _f(r.get("rmse")), _f(r.get("psi_over_G")), _f(r.get("peak_u")), _f(r.get("tv_u_rate")),
              f"{r.get('saturation'):.1%}"] for r in pp]),
    }


def report_context(st: Study, data: str, cmd: str, wall_s: float | None) -> dict:
    """Everything templates/paper.md.j2 cites."""
    cfg, rec = st.cfg, st.rec
    ctx = dict(cfg=cfg, rec=rec, cmd=cmd, version=__version__, timings=st.timings, wall_s=wall_s,
               cpu_s=_cpu_seconds(), cpus=os.cpu_count(), threads=nb.get_num_threads(), NS=NS,
               thresholds=dict(TRACK_TOL=TRACK_TOL, SLIGHT_TOL=SLIGHT_TOL, EDGE_TOL=EDGE_TOL, OSC_RATIO=OSC_RATIO,
                               OSC_PAPER=OSC_PAPER, SUPPRESS=SUPPRESS, C4_TOL=C4_TOL, CHATTER_STRONG=CHATTER_STRONG,
                               CHATTER_WINDOW=CHATTER_WINDOW, MATTERS=MATTERS, SAT_MATTERS=SAT_MATTERS,
                               REC_ABS=REC_ABS),
               by_group=sorted(st.timings.get("by_group", {}).items(), key=lambda kv: -kv[1]),
               math=math, G_NOMINAL=G_NOMINAL, claim_period=CLAIM_PERIOD,
               env_agreement=env_agreement(st))
    ctx.update(paper_tables(st))
    ctx.update(claims_context(st, data))
    ctx.update(regions=facts.regions(st), div=facts.divergence_facts(st), probes=facts.probe_facts(st),
               lim=facts.limit_facts(st),
               fr=facts.fr_facts(st), n_counts=facts.n_matters_counts(st), lost=facts.lost_track(st),
               smooth_rows=md_table(["n", "w", "diverged", "RMSE quiet", "friction peak", "rec. on [s]",
                                     "TV rate [mA/s]", "saturation"], facts.smoothing_rows(st, "smoothing")),
               smooth_pos_rows=md_table(["n", "w", "diverged", "RMSE quiet [rad]", "friction peak [rad]",
                                         "rec. on [s]", "TV rate [mA/s]", "saturation"],
                                        facts.smoothing_rows(st, "smoothing_position")),
               smooth_gain=facts.smoothing_gain(st, "smoothing", rec["smoothing"]),
               smooth_gain_pos=facts.smoothing_gain(st, "smoothing_position", rec["smoothing_position"]),
               period_rows=md_table(["h [s]", "best sigma", "RMSE quiet", "saturation"],
                                    facts.period_rows(rec["period_table"])),
               pos_period_rows=md_table(["h [s]", "best sigma", "RMSE quiet [rad]", "saturation"],
                                        facts.period_rows(rec["pos_period_table"])),
               best_n=facts.best_by_n(st, "sigma_period", rec["h_paper"]), qmax=facts.qmax,
               p3=runs_by_set(st, "P3"), p4=runs_by_set(st, "P4"), p1=runs_by_set(st, "P1"), p2=runs_by_set(st, "P2"),
               p3_old=runs_by_set(st, "P3_old"), d_m=PlantParams().d_m,
               dist_limit_rows=md_table(["limit [mA]", "lost", "mean RMSE", "median RMSE", "mean saturation"],
                                        [[f"{k:g}", f"{v[0]:.1%}", _f(v[1]), _f(v[2]), f"{v[3]:.2%}"]
                                         for k, v in rec["dist_limit_table"].items()]))
    return ctx


def write_report(st: Study, out: str, cmd: str, t_start: float | None = None) -> str:
    """Write REPORT.md, figures/, data/ and recommended_defaults.json under ``out``; returns REPORT.md's path."""

    figs, data = os.path.join(out, "figures"), os.path.join(out, "data")
    os.makedirs(figs, exist_ok=True)
    os.makedirs(data, exist_ok=True)
    t0 = time.perf_counter()
    run_plot_jobs(figure_jobs(st, figs, cmd), workers=2)
    write_data(st, data)
    rec_json = recommendation_json(st)
    atomic_write_text(os.path.join(out, "recommended_defaults.json"), json.dumps(rec_json, indent=2) + "\n")
    st.timings["plots_s"] = time.perf_counter() - t0
    wall_s = time.perf_counter() - t_start if t_start is not None else None
    md = render("paper.md.j2", **report_context(st, data, cmd, wall_s))
    path = os.path.join(out, "REPORT.md")
    atomic_write_text(path, md)
    return path
