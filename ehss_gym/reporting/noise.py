"""The noise study's report (``ehss noise``): figures, CSV tables and numbers computed here, prose in the template
templates/noise.md.j2.

:func:`write_noise_report` writes ``REPORT.md``, ``figures/``, ``data/`` and ``recommended.json`` (the settings the
env's :data:`~ehss_gym.envs.config.DEFAULTS` restate; a test checks it).
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import time

import numpy as np

from ehss_gym._version import __version__
from ehss_gym.core.filters import butterworth_coefficients
from ehss_gym.core.params import PlantParams
from ehss_gym.core.physics import lie_derivatives
from ehss_gym.infra.fmt import fmt_num as _f
from ehss_gym.infra.fmt import md_table
from ehss_gym.infra.util import atomic_write_text
from ehss_gym.study.noise import (
    NoiseStudy,
    final_variants,
    grid_cells,
    ls_sigma0,
    old_template,
    startup_variants,
)
from ehss_gym.study.noise_config import ENV_NOISE_MAX, NS, REALISTIC_SOURCES, TASKS
from ehss_gym.study.noise_rules import is_lost, summary

from .noise_figures import plot_channels, plot_n_spread, plot_noise_maps, plot_step
from .render import render

G_NOMINAL = 3.1e6  # input gain of s near rest [unit of s / s per mA] (docs/MODEL.md)
MATTERS = 1.5  # n "changes the outcome" of a metric when max/min over n >= 1.5 (the reproduction study's)


def _pairs(st: NoiseStudy) -> list:
    return [(e, lw) for e, _ in st.cfg.estimators for lw, _ in st.cfg.laws]


def _rows(st: NoiseStudy) -> list:
    return [r for r, _ in st.cfg.noise_rows()]


def _spread(vals) -> float:
    vals = [v for v in vals if math.isfinite(v)]
    if len(vals) < 2:
        return math.nan
    lo, hi = min(vals), max(vals)
    return hi / lo if lo > 0 else (math.inf if hi > 0 else 1.0)


def n_spread(st: NoiseStudy, task: str) -> dict:
    """((estimator, law), row) -> metric -> max/min over n of the cell medians."""
    cells = {n: grid_cells(st, task, n) for n in NS}
    return {(p, r): {k: _spread([cells[n][p][r][k] for n in NS]) for k in ("rmse_quiet", "fric", "tv")}
            for p in _pairs(st) for r in _rows(st)}


# --- facts -------------------------------------------------------------------------------------------------


def startup_context(st: NoiseStudy) -> dict:
    """The start-up table: lost episodes per variant, task and suite, also restricted to the old loop's lost ones."""
    cfg = st.cfg
    rows = []
    lost_old = {}
    for task in TASKS:
        for suite in ("random", "heldout"):
            lost_old[(task, suite)] = [i for i, r in enumerate(st.group(f"start|{task}|old|{suite}"))
                                       if is_lost(r, cfg.lost_rms)]
    labels = [lab for lab, _, _ in startup_variants(cfg, "position")]
    vel = {lab for lab, _, _ in startup_variants(cfg, "velocity")}
    for lab in labels:
        cells = []
        for task in TASKS:
            tl = lab if task == "position" or lab in vel else None
            if tl is None:
                cells += ["", ""]
                continue
            for suite in ("random", "heldout"):
                recs = st.group(f"start|{task}|{tl}|{suite}")
                old_idx = lost_old[(task, suite)]
                n_all = sum(is_lost(r, cfg.lost_rms) for r in recs)
                n_old = sum(is_lost(recs[i], cfg.lost_rms) for i in old_idx)
                cells.append(f"{n_all} ({n_old} of {len(old_idx)})")
        med = [summary(st.group(f"start|{t}|{lab if (t == 'position' or lab in vel) else 'old'}|heldout"),
                       cfg.lost_rms) for t in TASKS]
        rows.append([lab, *cells, _f(med[0]["rmse"]), _f(med[1]["rmse"]), _f(med[1]["sat"], ".2%")])
    hdr = ["variant", "velocity random", "velocity held-out", "position random", "position held-out",
           "median RMSE vel. (held-out)", "median RMSE pos. (held-out)", "mean saturation pos. (held-out)"]
    fam = {}
    for task in TASKS:
        hs = st.group(f"start|{task}|old|heldout")
        fam[task] = sorted({r.features.get("family") for i, r in enumerate(hs) if i in lost_old[(task, "heldout")]})
    fam_p = sorted({r.features.get("family") for r in st.group("start|position|P|heldout")
                    if is_lost(r, cfg.lost_rms)})
    return {"startup_table": md_table(hdr, rows), "startup_choice": st.rec["startup"], "lost_old": lost_old,
            "lost_families": fam, "lost_families_p": fam_p, "startup_rule_table": st.rec["startup_table"],
            "g_ratio": g_domain_ratio()}


def g_domain_ratio() -> float:
    """The model's G at the edge of its pressure domain (|x3| = 0.95 P_s, the valve opening to that side) over G
    at rest."""
    p = PlantParams()
    hd = np.zeros(4)
    _, g0 = lie_derivatives(np.zeros(4), p.as_array(), 3, hd)
    _, g1 = lie_derivatives(np.array([0.0, 0.0, -0.95 * p.P_s, -1e-7]), p.as_array(), 3, hd)
    return g1 / g0


def ls_context(st: NoiseStudy) -> dict:
    cfg = st.cfg
    out = {}
    for task in TASKS:
        rows = []
        for lab in ("0x", "1x"):
            ref = st.cell(f"ls|{task}|ref|{lab}")
            rows.append([f"Sontag, sigma = {old_template(task).sigma:g}", lab, _f(ref["rmse_quiet"]), _f(ref["tv"]),
                         _f(ref["fric"]), ref["n_lost"]])
        for sg in cfg.sigmas_ls(task):
            for lab in ("0x", "1x"):
                c = st.cell(f"ls|{task}|{sg:g}|{lab}")
                star = " (chosen)" if sg == st.rec[f"ls_sigma_{task}"] else ""
                rows.append([f"Lin-Sontag, sigma = {sg:g}{star}", lab, _f(c["rmse_quiet"]), _f(c["tv"]),
                             _f(c["fric"]), c["n_lost"]])
        out[task] = md_table(["law", "noise", "median quiet RMSE", "median TV [mA/s]", "median friction peak",
                              "lost"], rows)
    tm = old_template("velocity")
    return {"ls_tables": out, "ls_sigma0": {t: ls_sigma0(old_template(t).sigma, tm.current_limit) for t in TASKS}}


def tv_slope(cells: dict, pair, rows: list) -> float:
    """Exponent p of TV ~ k^p over the noise levels where the TV is at least 3x the noise-free TV."""
    base = cells[pair]["0x"]["tv"]
    pts = [(float(r[:-1]), cells[pair][r]["tv"]) for r in rows if r not in ("0x", "realistic")]
    pts = [(k, v) for k, v in pts if k > 0 and math.isfinite(v) and v >= 3 * base]
    if len(pts) < 2:
        return math.nan
    x, y = np.log10([p[0] for p in pts]), np.log10([p[1] for p in pts])
    return float(np.polyfit(x, y, 1)[0])


def mechanism_context(st: NoiseStudy) -> dict:
    """The numbers behind the mechanism of each map region (n = 2)."""
    cfg = st.cfg
    rows = _rows(st)
    out = {}
    for task in TASKS:
        cells = grid_cells(st, task)
        est = [e for e, _ in cfg.estimators]
        t = {"tv": {e: {r: cells[(e, "sontag")][r]["tv"] for r in rows} for e in est},
             "fric0": {e: cells[(e, "sontag")]["0x"]["fric"] for e in est},
             "q0": {e: cells[(e, "sontag")]["0x"]["rmse_quiet"] for e in est},
             "slope": {e: tv_slope(cells, (e, "sontag"), rows) for e in est},
             "sat1": {p: cells[p]["1x"]["sat"] for p in cells},
             "lost_cells": [(p, r, cells[p][r]["n_lost"]) for p in cells for r in rows if cells[p][r]["n_lost"]],
             "al_ratio": {(e, r): cells[(e, "sontag+al")][r]["tv"] / max(cells[(e, "sontag")][r]["tv"], 1e-12)
                          for e in est for r in rows if (e, "sontag+al") in cells},
             "ls_ratio": {(e, r): cells[(e, "lin-sontag")][r]["tv"] / max(cells[(e, "sontag")][r]["tv"], 1e-12)
                          for e in est for r in rows if (e, "lin-sontag") in cells}}
        chan = {}
        for e in est:
            for r in ("1x", "realistic"):
                v = [summary(st.group(f"chan|{task}|{e}|{c}|{r}"), cfg.lost_rms)["tv"] for c in range(4)]
                chan[r, e] = (int(np.nanargmax(v)) if np.isfinite(v).any() else -1, v)
        t["chan"] = chan
        out[task] = t
    return {"mech": out}


def noise_gain_facts(st: NoiseStudy) -> dict:
    """Order-of-magnitude noise in the law's current per control step, from the derivation (docs/MODEL.md).

    velocity: psi carries l1 e^(2) + l0 e^(1); the SVF's e^(2) carries c0 = w_e^2 times the output's noise, the state
    estimates' e^(1) carries d_m/J times the pressure noise and e^(2) (d_m/J) C c_d sqrt(P_s/rho) times the valve
    noise. position: psi carries l2 e^(3) + l1 e^(2) + l0 e^(1); the SVF's e^(3) carries w_e^3 times the position
    noise, the state estimates' e^(2) the pressure term and e^(3) the valve term. The current's noise is that over G
    (about 3.1e6 near rest); white noise in u of std d gives a control TV of about 2/sqrt(pi) d per step.
    """
    p = old_template("velocity").plant
    C = 4 * p.beta / p.V_m
    qv = p.d_m / p.J * C * p.c_d * math.sqrt(p.P_s / p.rho)  # y'' per unit of valve area [rad/s^3 / m^2]
    out = {}
    for task in TASKS:
        tm = old_template(task)
        lam = lambdas_of(tm)
        we = 2 * math.pi * tm.estimator_hz
        f_s = 1.0 / tm.control_period
        for row, noise in st.cfg.noise_rows():
            if row not in ("1x", "realistic"):
                continue
            if task == "velocity":
                svf = lam[1] * we**2 * noise[1]
                state = math.hypot(lam[0] * p.d_m / p.J * noise[2], lam[1] * qv * noise[3])
            else:
                svf = lam[2] * we**3 * noise[0]
                state = math.hypot(lam[1] * p.d_m / p.J * noise[2], lam[2] * qv * noise[3], lam[0] * noise[1])
            for name, psi in (("svf", svf), ("state", state)):
                du = psi / G_NOMINAL
                out[(task, row, name)] = {"psi": psi, "du": du, "tv": 2 / math.sqrt(math.pi) * du * f_s}
    return out


def lambdas_of(sc) -> list:
    """lambda_0 .. lambda_2 of a scenario's combined error (zero-padded)."""
    lam = [float(v) for v in butterworth_coefficients(sc.order - 1, sc.fr)]
    return lam + [0.0] * (3 - len(lam))


def _tables_mechanism(st: NoiseStudy, mech: dict) -> dict:
    """Markdown tables of the mechanism facts."""
    rows = _rows(st)
    est = [e for e, _ in st.cfg.estimators]
    names = ("x1", "x2", "x3", "x4")
    out = {}
    for task in TASKS:
        m = mech[task]
        tv_rows = [[e] + [_f(m["tv"][e][r]) for r in rows] + [_f(m["slope"][e], ".2f"), _f(m["fric0"][e]),
                                                             _f(m["q0"][e])] for e in est]
        out[f"tv_{task}"] = md_table(["estimator (Sontag, n = 2)"] + [f"TV {r}" for r in rows]
                                     + ["TV ~ k^p: p", "friction peak 0x", "quiet RMSE 0x"], tv_rows)
        ch_rows = [[e] + [_f(v) for v in m["chan"][r, e][1]] + [names[m["chan"][r, e][0]]]
                   for r in ("1x", "realistic") for e in est]
        for i, r in enumerate([r for r in ("1x", "realistic") for _ in est]):
            ch_rows[i].insert(1, r)
        out[f"chan_{task}"] = md_table(["estimator", "noise on one channel"] + [f"TV, {n} only" for n in names]
                                       + ["dominant"], ch_rows)
    return out


def choice_context(st: NoiseStudy) -> dict:
    """The rule's admissible and kept pairs with their numbers, per task."""
    out = {}
    for task in TASKS:
        cells = grid_cells(st, task)
        adm = set(st.rec[f"admissible_{task}"])
        kept = set(st.rec[f"kept_{task}"])
        rows = []
        for p in _pairs(st):
            c0, c1 = cells[p]["0x"], cells[p]["1x"]
            lost_env = sum(cells[p][r]["n_lost"] for r in ("0x", "0.1x", "0.3x", "1x") if r in cells[p])
            tag = "**chosen**" if p == st.rec[f"choice_{task}"] else ("kept" if p in kept else
                                                                       ("admissible" if p in adm else "-"))
            rows.append([f"{p[0]} / {p[1]}", lost_env, _f(c1["sat"], ".2%"), _f(c0["rmse_quiet"]), _f(c1["fric"]),
                         _f(c1["tv"]), tag])
        out[task] = md_table(["estimator / law", "lost (0..1x)", "saturation 1x", "quiet RMSE 0x",
                              "friction peak 1x", "TV 1x [mA/s]", "rule"], rows)
    return {"choice_tables": out}


def _final_numbers(recs: list, lost_rms: float) -> dict:
    """Per-suite numbers of a list of Records or metric dicts: medians on the noisy and noise-free halves."""
    def get(r, k):
        return r.get(k)

    noisy = np.array([bool(r["noisy"]) if isinstance(r, dict) else bool(r.params["noisy"]) for r in recs])
    tv = np.array([get(r, "tv_u_rate") for r in recs], dtype=float)
    rm = np.array([get(r, "rmse") for r in recs], dtype=float)
    rr = np.array([get(r, "rmse_r") for r in recs], dtype=float)
    sat = np.array([get(r, "saturation") for r in recs], dtype=float)
    lost = np.array([is_lost(r, lost_rms) for r in recs])

    def med(a, sel):
        a = a[sel & np.isfinite(a)]
        return float(np.median(a)) if a.size else math.nan

    every = np.ones(len(recs), dtype=bool)
    return {"tv_noisy": med(tv, noisy), "tv_clean": med(tv, ~noisy), "rmse_noisy": med(rm, noisy),
            "rmse_clean": med(rm, ~noisy), "rmse_mean": float(np.nanmean(rm)), "rmse_r_mean": float(np.nanmean(rr)),
            "rmse_median": med(rm, every), "sat_mean": float(np.mean(sat)), "lost": int(lost.sum()),
            "n": len(recs), "n_noisy": int(noisy.sum())}


def final_context(st: NoiseStudy) -> dict:
    """New defaults against the old ones, the named variants and the PID; the Must-show numbers."""
    cfg = st.cfg
    nums = {}
    for task in TASKS:
        for label in final_variants(st, task):
            for suite in ("random", "heldout"):
                recs = st.group(f"final|{task}|{label}|{suite}")
                nums[(task, label, suite)] = _final_numbers(recs, cfg.lost_rms)
        for which in ("old", "new"):
            for suite in ("random", "heldout"):
                nums[(task, f"pid-{which}", suite)] = _final_numbers(st.rec["pid"][(task, which, suite)],
                                                                     cfg.lost_rms)
    rows = []
    for task in TASKS:
        for label in list(final_variants(st, task)) + ["pid-old", "pid-new"]:
            for suite in ("random", "heldout"):
                x = nums[(task, label, suite)]
                rows.append([task, label, suite, f"{x['lost']} of {x['n']}", _f(x["sat_mean"], ".2%"),
                             _f(x["rmse_median"]), _f(x["rmse_mean"]), _f(x["rmse_r_mean"]), _f(x["rmse_noisy"]),
                             _f(x["rmse_clean"]), _f(x["tv_noisy"]), _f(x["tv_clean"])])
    hdr = ["task", "loop", "suite", "lost", "mean saturation", "median RMSE", "mean RMSE", "mean RMSE vs r",
           "median RMSE noisy", "median RMSE noise-free", "median TV noisy [mA/s]", "median TV noise-free [mA/s]"]
    v_old, v_new = nums[("velocity", "old", "heldout")], nums[("velocity", "new", "heldout")]
    p_new, p_pid = nums[("position", "new", "heldout")], nums[("position", "pid-old", "heldout")]
    must = {
        "tv_ratio": v_old["tv_noisy"] / max(v_new["tv_noisy"], 1e-12),
        "tv_ratio_issue": 6.1e4 / max(v_new["tv_noisy"], 1e-12),
        "v_old": v_old, "v_new": v_new, "p_new": p_new, "p_pid": p_pid,
        "p_pid_new": nums[("position", "pid-new", "heldout")], "p_old": nums[("position", "old", "heldout")],
        "lost_new": {t: nums[(t, "new", "heldout")]["lost"] for t in TASKS},
        "lost_new_random": {t: nums[(t, "new", "random")]["lost"] for t in TASKS},
    }
    low = nums.get(("velocity", "lowest-tv", "heldout"))
    if low is not None:  # what the rule's tracking tolerance costs: the admissible pair with the lowest TV
        must["low"] = {"pair": st.rec["lowtv_velocity"], "tv_ratio": v_old["tv_noisy"] / max(low["tv_noisy"], 1e-12),
                       "v": low, "rmse_noisy_rel": low["rmse_noisy"] / v_old["rmse_noisy"] - 1.0,
                       "rmse_clean_rel": low["rmse_clean"] / v_old["rmse_clean"] - 1.0}
        q = grid_cells(st, "velocity")
        ch = st.rec["choice_velocity"]
        must["low"]["quiet0_ratio"] = q[st.rec["lowtv_velocity"]]["0x"]["rmse_quiet"] / q[ch]["0x"]["rmse_quiet"]
        must["low"]["quiet1_ratio"] = q[st.rec["lowtv_velocity"]]["1x"]["rmse_quiet"] / q[ch]["1x"]["rmse_quiet"]
    must["kept_svf_only"] = all(dict(cfg.estimators)[k[0]][0] == ("estimator", "foh") for k in
                                st.rec["kept_velocity"]) if st.rec["kept_velocity"] else False
    must["v_rmse_rel"] = v_new["rmse_noisy"] / v_old["rmse_noisy"] - 1.0
    must["v_clean_rel"] = v_new["rmse_clean"] / v_old["rmse_clean"] - 1.0
    must["tv_met"] = must["tv_ratio"] >= 100.0
    must["v_rmse_met"] = v_new["rmse_noisy"] <= v_old["rmse_noisy"]
    must["v_clean_met"] = v_new["rmse_clean"] <= v_old["rmse_clean"] and v_new["tv_clean"] <= v_old["tv_clean"]
    must["p_met"] = p_new["lost"] == 0 and p_new["sat_mean"] < 0.05 and p_new["rmse_mean"] < p_pid["rmse_mean"]
    must["lost_met"] = all(nums[(t, "new", "heldout")]["lost"] <= cfg.max_lost * nums[(t, "new", "heldout")]["n"]
                           for t in TASKS)
    return {"final_table": md_table(hdr, rows), "must": must, "pid_gains": {k: v for k, v in st.rec["pid"].items()
                                                                           if k[2] == "gains"}}


def nmatters_context(st: NoiseStudy) -> dict:
    """n = 2, 4, 6 at the new defaults: the paper run, the randomised scenarios, and the maps' spread over n."""
    rows = []
    for task in TASKS:
        for n in NS:
            p = st.group(f"nmat|{task}|{n}|paper")[0]
            c = st.cell(f"nmat|{task}|{n}|random")
            rows.append([task, n, _f(p.get("rmse_quiet_true")), _f(p.get("max_abs_e_friction_true")),
                         _f(p.get("tv_u_rate")), _f(p.get("saturation"), ".2%"), _f(c["rmse"]), _f(c["rmse_quiet"]),
                         _f(c["fric"]), _f(c["tv"]), f"{c['n_lost']} of {c['n']}"])
    hdr = ["task", "n", "paper: quiet RMSE", "paper: friction peak", "paper: TV [mA/s]", "paper: saturation",
           "random: median RMSE", "random: median quiet RMSE", "random: median friction peak",
           "random: median TV", "random: lost"]
    spread = {}
    counts = {}
    for task in TASKS:
        sp = n_spread(st, task)
        spread[task] = sp
        cells = [(p, r) for p in _pairs(st) for r in _rows(st)]
        matters = [(p, r) for p, r in cells if any(v >= MATTERS for v in sp[(p, r)].values() if math.isfinite(v))]
        chosen = st.rec[f"choice_{task}"]
        at_default = {r: sp[(chosen, r)] for r in _rows(st)}
        counts[task] = {"matters": len(matters), "cells": len(cells), "examples": matters[:6],
                        "at_default": at_default}
    def_rows = [[task, r] + [_f(counts[task]["at_default"][r][k], ".3g") for k in ("rmse_quiet", "fric", "tv")]
                for task in TASKS for r in _rows(st)]
    return {"n_table": md_table(hdr, rows), "n_counts": counts, "n_spread": spread, "n_plain": n_plain(st),
            "n_default_table": md_table(["task", "noise", "quiet RMSE max/min over n", "friction peak max/min",
                                         "TV max/min"], def_rows)}


N_METRICS = (("rmse_quiet", "quiet RMSE"), ("fric", "friction peak"), ("tv", "control TV"), ("rmse", "RMSE"))


def n_plain(st: NoiseStudy) -> dict:
    """Per task, at the new defaults on the randomised scenarios: each metric's ratio n = 4 and n = 6 over n = 2,
    which metrics n changes by >= MATTERS (either way), and the n with the lowest quiet RMSE."""
    out = {}
    for task in TASKS:
        c = {n: st.cell(f"nmat|{task}|{n}|random") for n in NS}
        ratios = {k: {n: c[n][k] / c[2][k] if c[2][k] > 0 else math.nan for n in NS if n != 2} for k, _ in N_METRICS}
        moved = [(label, ratios[k]) for k, label in N_METRICS
                 if any(math.isfinite(v) and (v >= MATTERS or v <= 1.0 / MATTERS) for v in ratios[k].values())]
        best = min(NS, key=lambda n: (c[n]["rmse_quiet"], n))
        paper = [st.group(f"nmat|{task}|{n}|paper")[0] for n in NS]
        spreads = [_spread([p.get(k) for p in paper]) for k in ("rmse_quiet_true", "max_abs_e_friction_true",
                                                                  "tv_u_rate")]
        spreads = [v for v in spreads if math.isfinite(v)]
        out[task] = {"moved": moved, "best_quiet": best, "lost": {n: c[n]["n_lost"] for n in NS},
                     "paper_spread": max(spreads) if spreads else math.nan}
    return out


def bias_context(st: NoiseStudy) -> dict:
    rows = []
    for (task, label), b in st.rec["bias"].items():
        rows.append([task, label, _f(b["b1_rms"]), _f(b["bs_rms"]), _f(b["b1_agree"], ".2e"), _f(b["b2_agree"], ".2e"),
                     _f(b["bs_agree"], ".2e"), _f(b["bs_fric_mean"]), _f(b["e_pred_fric"]), _f(b["e_fric"])])
    hdr = ["task", "plant scaling", "RMS b1 measured", "RMS b_s measured", "b1: rel. RMS (derived - measured)",
           "b2: rel. RMS", "b_s: rel. RMS", "mean b_s in friction (derived)", "e predicted -b_s/l0",
           "e measured (friction, mean)"]
    worst = max(b["bs_agree"] for b in st.rec["bias"].values())
    # the quasi-static reading e = -b_s/lambda_0, per task: the worst ratio of measured to predicted friction offset
    quasi = {}
    for task in TASKS:
        rs = [b["e_fric"] / b["e_pred_fric"] for (t, _), b in st.rec["bias"].items()
              if t == task and math.isfinite(b["e_pred_fric"]) and b["e_pred_fric"] != 0.0]
        quasi[task] = {"ratio_lo": min(rs) if rs else math.nan, "ratio_hi": max(rs) if rs else math.nan,
                       "holds": bool(rs) and all(0.5 <= r <= 2.0 for r in rs)}
    return {"bias_table": md_table(hdr, rows), "bias_worst": worst, "bias_quasi": quasi}


def recommendation_json(st: NoiseStudy) -> dict:
    """What the env's DEFAULTS restate (per task: estimator, law, sigma, ...; global: the pressure domain)."""
    out = {"generated_by": "ehss noise", "ehss_gym_version": __version__, "quick_mode": st.cfg.quick,
           "pressure_domain": st.rec["pressure_domain"], "startup": st.rec["startup"]}
    for task in TASKS:
        d = st.rec[f"defaults_{task}"]
        tm = old_template(task).replace(**d)
        out[task] = {"estimator": tm.estimator, "estimator_hz": tm.estimator_hz, "observer_hz": tm.observer_hz,
                     "law": tm.law, "sigma": tm.sigma, "layer_gain": tm.layer_gain, "bumpless": tm.bumpless,
                     "ref_accel": tm.ref_accel, "choice": list(st.rec[f"choice_{task}"]),
                     "rule_met": st.rec[f"rule_met_{task}"],
                     "sigma_by_law": {"sontag": old_template(task).sigma, "lin-sontag": st.rec[f"ls_sigma_{task}"]},
                     "pid_direct_gains": list(st.rec["pid"][(task, "new", "gains")])}
    return out


# --- output ------------------------------------------------------------------------------------------------


def write_data(st: NoiseStudy, data: str) -> None:
    """The maps' cells (every n) and the final episodes as CSV."""
    buf = io.StringIO()
    w = csv.writer(buf)
    keys = ("rmse", "rmse_quiet", "rmse_r", "fric", "tv", "sat", "lost", "n_lost", "n")
    w.writerow(["task", "estimator", "law", "n", "noise"] + list(keys))
    for task in TASKS:
        for n in NS:
            cells = grid_cells(st, task, n)
            for (e, lw), rows in cells.items():
                for r, c in rows.items():
                    w.writerow([task, e, lw, n, r] + [c[k] for k in keys])
    atomic_write_text(os.path.join(data, "grid.csv"), buf.getvalue())
    buf = io.StringIO()
    w = csv.writer(buf)
    mk = ("rmse", "rmse_true", "rmse_r", "rmse_quiet_true", "max_abs_e_friction_true", "tv_u_rate", "saturation",
          "window_rms_max")
    w.writerow(["group", "episode"] + list(mk))
    for g, recs in st.records.items():
        if g.startswith(("final|", "start|")):
            for i, r in enumerate(recs):
                w.writerow([g, i] + [r.get(k) for k in mk])
    atomic_write_text(os.path.join(data, "episodes.csv"), buf.getvalue())


def figures(st: NoiseStudy, figs: str, cmd: str) -> dict:
    rows, pairs = _rows(st), _pairs(st)
    out = {}
    for task in TASKS:
        for n in NS:
            name = f"noise_maps_{task}_n{n}.png"
            plot_noise_maps(grid_cells(st, task, n), rows, pairs, task, n, os.path.join(figs, name), cmd)
            out[(task, n)] = name
        plot_n_spread(n_spread(st, task), rows, pairs, task, os.path.join(figs, f"n_spread_{task}.png"), cmd)
    est = [e for e, _ in st.cfg.estimators]
    chan = {(t, e, c, r): summary(st.group(f"chan|{t}|{e}|{c}|{r}"), st.cfg.lost_rms)["tv"]
            for t in TASKS for e in est for c in range(4) for r in ("1x", "realistic")}
    plot_channels(chan, est, ["1x", "realistic"], os.path.join(figs, "noise_channels.png"), cmd)
    for i in st.rec["examples"]:
        trs = [st.group(f"example|{i}|{lab}")[0].traj for lab in ("old", "P", "new")]
        plot_step(trs, ["the legacy loop", "+ the model's pressure domain", "the new defaults"],
                  os.path.join(figs, f"startup_example_{i}.png"), cmd,
                  f"held-out position episode {i} ({trs[0].scenario.reference.description[:60]})")
    return out


def write_noise_report(st: NoiseStudy, out: str, cmd: str, t_start: float | None = None) -> str:
    """Write REPORT.md, figures/, data/ and recommended.json under ``out``; returns REPORT.md's path."""
    figs, data = os.path.join(out, "figures"), os.path.join(out, "data")
    os.makedirs(figs, exist_ok=True)
    os.makedirs(data, exist_ok=True)
    t0 = time.perf_counter()
    figures(st, figs, cmd)
    write_data(st, data)
    rec = recommendation_json(st)
    atomic_write_text(os.path.join(out, "recommended.json"), json.dumps(rec, indent=2) + "\n")
    st.timings["report_s"] = time.perf_counter() - t0
    mech = mechanism_context(st)
    ctx = {"cmd": cmd, "version": __version__, "cfg": st.cfg, "rec": st.rec, "timings": st.timings,
           "wall_s": (time.perf_counter() - t_start) if t_start is not None else None, "tasks": TASKS, "ns": NS,
           "env_noise": ENV_NOISE_MAX, "realistic": st.cfg.realistic, "realistic_sources": REALISTIC_SOURCES,
           "json": rec, "old": {t: old_template(t) for t in TASKS}, **startup_context(st), **ls_context(st), **mech,
           **_tables_mechanism(st, mech["mech"]), **choice_context(st), **final_context(st),
           **nmatters_context(st), **bias_context(st), "gain": noise_gain_facts(st)}
    md = render("noise.md.j2", **ctx)
    path = os.path.join(out, "REPORT.md")
    atomic_write_text(path, md)
    return path
