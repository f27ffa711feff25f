"""Numbers the reproduction report's prose cites, computed from the study's records (no prose here)."""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg

from ehss_gym.core.filters import butterworth_coefficients, companion
from ehss_gym.core.params import PlantParams
from ehss_gym.infra.fmt import fmt_axis, md_table
from ehss_gym.infra.fmt import fmt_num as _f
from ehss_gym.study.config import G_NOMINAL, NS, SAT_MATTERS
from ehss_gym.study.rules import attraction_bounds, cells_of, is_lost, lost_table, n_effect, n_matters
from ehss_gym.study.stages import Study


def _med(vals) -> float:
    vals = [v for v in vals if v is not None and math.isfinite(v)]
    return float(np.median(vals)) if vals else math.nan


def _frac(group) -> str:
    return f"{sum(n_matters(c) for _, c in group)}/{len(group)}" if group else "n/a"


def _spread(group, key) -> str:
    sps = [n_effect(c)[key][0] for _, c in group]
    sps = [s for s in sps if s is not None and math.isfinite(s)]
    return f"median x{np.median(sps):.2f}, max x{max(sps):.2f}" if sps else "n/a"


def _sat_list(c) -> str:
    return "/".join(f"{c[n].get('saturation'):.0%}" for n in NS if n in c)


def regions(st: Study) -> dict:
    """The sigma x period sweep's cells grouped by how they saturate, with the numbers each group's text cites."""
    cells = cells_of(st.group("sigma_period"), "sigma", "h")
    groups = {"relay": [], "coarse": [], "smooth": [], "trans": [], "other": []}
    for key, c in cells.items():
        live = [r for r in c.values() if not r.get("diverged", False)]
        if not live:
            continue
        sats = [r.get("saturation") for r in live]
        if min(sats) >= 0.95:
            groups["relay" if all(r.get("beta_log_limit") > 0 for r in live) else "coarse"].append((key, c))
        elif max(sats) <= 0.05:
            groups["smooth"].append((key, c))
        elif max(sats) - min(sats) >= SAT_MATTERS:
            groups["trans"].append((key, c))
        else:
            groups["other"].append((key, c))
    relay, smooth = groups["relay"], groups["smooth"]
    hs_relay = sorted({k[1] for k, _ in relay})
    mono_up = sum(1 for _, c in smooth if all(n in c for n in NS)
                  and c[2].get("rmse_quiet") < c[4].get("rmse_quiet") < c[6].get("rmse_quiet"))
    return {
        "n_cells": len(cells),
        "relay": {"count": len(relay), "sigmas": [k[0] for k, _ in relay], "hs": hs_relay, "frac": _frac(relay),
                  "beta_med": _med([r.get("beta_log_limit") for _, c in relay for r in c.values()]),
                  "rmse_spread": _spread(relay, "rmse_quiet"), "peak_spread": _spread(relay, "max_abs_e_friction"),
                  "rmse_by_h": [(h, [r.get("rmse_quiet") for k, c in relay if k[1] == h for r in c.values()])
                                for h in hs_relay[:5]]},
        "coarse": {"count": len(groups["coarse"]), "hs": [k[1] for k, _ in groups["coarse"]],
                   "sigmas": [k[0] for k, _ in groups["coarse"]], "frac": _frac(groups["coarse"]),
                   "beta_med": _med([r.get("beta_log_limit") for _, c in groups["coarse"] for r in c.values()]),
                   "rmse": [r.get("rmse_quiet") for _, c in groups["coarse"] for r in c.values()]},
        "smooth": {"count": len(smooth), "frac": _frac(smooth), "rmse_spread": _spread(smooth, "rmse_quiet"),
                   "ratio_med": _med([r.get("relay_log_ratio") for _, c in smooth for r in c.values()]),
                   "mono_up": mono_up},
        "trans": {"count": len(groups["trans"]), "frac": _frac(groups["trans"]),
                  "examples": [(k, _sat_list(c)) for k, c in sorted(groups["trans"], key=lambda kc: kc[0][::-1])[:4]]},
        "other": {"count": len(groups["other"]), "frac": _frac(groups["other"]),
                  "examples": [(k, _sat_list(c), "/".join(f"{c[n].get('beta_log_limit'):.1f}" for n in NS if n in c))
                               for k, c in sorted(groups["other"], key=lambda kc: kc[0][::-1])[:5]],
                  "all_above": all(r.get("beta_log_limit") > 0 for _, c in groups["other"] for r in c.values())},
    }


def divergence_facts(st: Study) -> dict:
    """P0 and the unlimited law's divergence by period, with the loop-gain argument's numbers."""
    dv = st.group("divergence")
    tds = [r.metrics["t_diverged"] for r in dv if r.metrics["diverged"]]
    G = _med([r.get("G_med") for g in ("sigma_period", "smoothing") for r in st.group(g)])
    G = G if math.isfinite(G) else G_NOMINAL
    hs = sorted({r.params["h"] for r in dv})
    rows = []
    for task, fr in sorted({(r.params["task"], r.params["fr"]) for r in dv}, key=lambda k: (k[0] != "velocity", -k[1])):
        for n in NS:
            row = [f"{task} {fr:g} Hz", str(n)]
            for h in hs:
                r = next((x for x in dv if x.params["h"] == h and x.params["task"] == task and x.params["fr"] == fr
                          and x.params["n"] == n), None)
                row.append("" if r is None else f"{r.metrics['t_diverged']:.3g} s ({r.metrics['divergence_reason']})"
                           if r.metrics["diverged"] else f"survived {r.params['t_end']:g} s")
            rows.append(row)
    p0 = st.group("P0")
    t0 = [r.metrics["t_diverged"] for r in p0 if r.metrics["diverged"]]
    return {"count": len(tds), "total": len(dv), "t_max": max(tds) if tds else math.nan, "hs": hs, "G": G,
            "durations": [(r.params["t_end"], r.params["h"]) for r in dv if r.params["n"] == 2
                          and r.params["fr"] == 100.0],
            "table": md_table(["config", "n"] + [f"h = {h:g} s" for h in hs], rows) if dv else "",
            "p0_count": len(t0), "p0_total": len(p0), "p0_t_max": max(t0) if t0 else math.nan}


def probe_facts(st: Study) -> list:
    """Relay limit-cycle probes: (frequency [Hz], h [s], estimator [Hz], RMS error)."""
    rows = sorted(st.group("probe"), key=lambda r: (r.params["estimator_hz"], r.params["h"]))
    return [(r.get("f_dom"), r.params["h"], r.params["estimator_hz"], r.get("e_rms_probe")) for r in rows]


def limit_facts(st: Study) -> dict:
    """Low and high current limits on the sigma x limit sweep."""
    sl = cells_of(st.group("sigma_limit"), "sigma", "limit")
    small = [(k, c) for k, c in sl.items() if k[1] is not None and k[1] <= 1.0 and 2 in c]
    big = [(k, c) for k, c in sl.items() if k[1] is not None and k[1] >= 1e3 and 2 in c]
    unl = [c[2] for k, c in sl.items() if k[1] is None and 2 in c and not c[2].get("diverged", False)]
    return {"any": bool(sl),
            "n_lost": sum(1 for _, c in small for r in c.values() if not math.isfinite(r.get("recovery_on"))
                          or r.get("diverged", False)),
            "n_small": sum(len(c) for _, c in small),
            "small_peaks": [r.get("max_abs_e_friction") for _, c in small for r in c.values()],
            "small_sats": [r.get("saturation") for _, c in small for r in c.values()],
            "unl_peak_u": [r.get("peak_u_applied") for r in unl],
            "big_tv": [c[n].get("tv_u_rate") for k, c in big if k[0] == 1.0 for n in c],
            "matters": f"{sum(n_matters(c) for c in sl.values())}/{len(sl)}"}


def fr_facts(st: Study) -> dict:
    """The sigma x f_r sweep: where the loop loses the reference, and where n matters."""
    sf = cells_of(st.group("sigma_fr"), "sigma", "fr")
    frs = sorted({k[1] for k in sf})

    def lost_share(fr):
        rs = [r for (sg, f), c in sf.items() if f == fr for r in c.values()]
        return sum(r.get("rmse_quiet") > 0.1 or r.get("diverged", False) for r in rs) / max(len(rs), 1)

    lost = [fr for fr in frs if lost_share(fr) >= 0.5]
    fr_lost = min(lost) if lost else None
    ok = [fr for fr in frs if fr_lost is None or fr < fr_lost]
    high = [(sg, f, n, r) for (sg, f), c in sf.items() if fr_lost is not None and f >= fr_lost for n, r in c.items()]
    exc = [(sg, f, n, r.get("rmse_quiet")) for sg, f, n, r in high
           if not r.get("diverged", False) and r.get("rmse_quiet") <= 0.1]
    by_sig = [(sg, sum(n_matters(c) for (s_, f), c in sf.items() if s_ == sg and f in ok))
              for sg in sorted({k[0] for k in sf})]
    r1 = [(f, c[2].get("rmse_quiet")) for (sg, f), c in sorted(sf.items()) if sg == 1.0 and 2 in c and f in ok]
    return {"any": bool(sf), "fr_lost": fr_lost, "ok": ok, "n_high": len(high), "exc": exc, "by_sig": by_sig,
            "r1": r1, "lost_rmse": [r.get("rmse_quiet") for *_, r in high if r.get("rmse_quiet") > 0.1]}


def n_matters_counts(st: Study) -> list:
    """(sweep, cells where n changes the outcome, cells) for each sweep."""
    out = []
    for g, row, col in (("sigma_period", "sigma", "h"), ("position_sigma_period", "sigma", "h"),
                        ("sigma_limit", "sigma", "limit"), ("sigma_fr", "sigma", "fr"),
                        ("position_sigma", "sigma", "task")):
        cells = cells_of(st.group(g), row, col)
        if cells and any(len(c) > 1 for c in cells.values()):
            out.append((g, sum(n_matters(c) for c in cells.values()), len(cells)))
    return out


def _lost_row(t: dict) -> tuple:
    return next(iter(t.values())) if t else (math.nan, math.nan, math.nan, math.nan, 0)


def lost_track(st: Study) -> dict:
    """Old loop, fixed loop, new defaults on the randomised and held-out scenarios; the maps; the start-up probe."""
    cfg, rec = st.cfg, st.rec
    lr = cfg.lost_rms
    final = {}
    for task in ("velocity", "position"):
        for kind in ("old", "fixed", "new"):
            for suite in ("random", "heldout"):
                final[(task, kind, suite)] = _lost_row(lost_table(st.group(f"final_{task}_{suite}_{kind}"),
                                                                  ("task",), lr))
    roa = attraction_bounds(st.group("roa"), lr)
    dist = rec["dist_table"]
    return {"final": final, "roa": roa, "roa_frs": sorted({k[0] for k in roa}),
            "roa_keys": sorted({(k[1], k[2]) for k in roa}, key=lambda k: (k[1] != cfg.estimator, k[0])),
            "dist_rows": [[f"{k[0]:g}", f"{k[1]:g}", fmt_axis(k[2]), f"{v[0]:.0%}", _f(v[2]), f"{v[3]:.2%}"]
                          for k, v in dist.items()],
            "map_old": lost_table(st.group("map_old"), ("fr", "sigma"), lr),
            "map_w": lost_table(st.group("map_smoothing"), ("fr", "smoothing"), lr),
            "map_lim": lost_table(st.group("map_limit"), ("fr", "limit"), lr),
            "pos_rows": [[f"{k[1]:g}", fmt_axis(k[2]), f"{v[0]:.0%}", _f(v[2]), f"{v[3]:.1%}"]
                         for k, v in rec["pos_dist_table"].items()],
            "start_errors": _start_errors(st),
            "families": {k: _by_family(st, g) for k, g in (("velocity_fixed", "final_velocity_random_fixed"),
                                                          ("position_new", "final_position_random_new"))},
            "step_accel": step_peak_derivative(4, 20.0, 2), "accel_max": _accel_max()}


def _by_family(st: Study, group: str) -> list:
    """(reference family, lost share, episodes) of a randomised-scenario group."""
    fams: dict = {}
    for r in st.group(group):
        fams.setdefault(r.features["family"], []).append(is_lost(r, st.cfg.lost_rms))
    return [(f, float(np.mean(v)), len(v)) for f, v in sorted(fams.items())]


def step_peak_derivative(order: int, hz: float, i: int) -> float:
    """Peak |y_d^(i)| of the continuous reference model's response to a unit step [unit / s^i]."""
    A, b = companion(butterworth_coefficients(order, hz))
    dt = 1e-5
    E = scipy.linalg.expm(np.block([[A * dt, b[:, None] * dt], [np.zeros((1, order + 1))]]))
    x = np.zeros(order)
    peak = 0.0
    for _ in range(int(round(0.5 / dt))):  # 0.5 s covers the transient of a >= 5 Hz filter
        x = E[:order, :order] @ x + E[:order, order]
        d = (A @ x + b)[i - 1] if i == order else x[i]
        peak = max(peak, abs(d))
    return peak


def _accel_max() -> float:
    """The largest angular acceleration the motor can give the load: P_s d_m / J [rad/s^2]."""
    p = PlantParams()
    return p.P_s * p.d_m / p.J


def _start_errors(st: Study) -> dict:
    """Initial error |r(0)| of the lost and the kept randomised episodes of the old defaults with the fixed filters."""
    recs = st.group("final_velocity_random_fixed")
    flags = [is_lost(r, st.cfg.lost_rms) for r in recs]
    lost = [abs(r.features["r0"]) for r, f in zip(recs, flags) if f]
    kept = [abs(r.features["r0"]) for r, f in zip(recs, flags) if not f]
    return {"lost_min": min(lost) if lost else math.nan, "kept_max": max(kept) if kept else math.nan,
            "n_lost": len(lost), "n": len(recs)}


def smoothing_rows(st: Study, group: str) -> list:
    return [[r.params["n"], f"{r.params['smoothing']:g}", "diverged" if r.metrics["diverged"] else "no",
             _f(r.get("rmse_quiet")), _f(r.get("max_abs_e_friction")), _f(r.get("recovery_on")),
             _f(r.get("tv_u_rate")), f"{r.get('saturation'):.2%}"]
            for r in sorted(st.group(group), key=lambda r: (r.params["n"], r.params["smoothing"]))]


def smoothing_gain(st: Study, group: str, w: float):
    """(plain n = 2 record, chosen-width n = 2 record) of a smoothing study, or None."""
    plain = next((r for r in st.group(group) if r.params["smoothing"] == 0.0 and r.params["n"] == 2), None)
    chosen = next((r for r in st.group(group) if r.params["smoothing"] == w and r.params["n"] == 2), None)
    return (plain, chosen) if plain and chosen else None


def qmax(limit_ma: float) -> float:
    """Unloaded valve flow at a current [mA]: c_d K u sqrt(P_s / rho) [m^3/s] (Table I values)."""
    p = PlantParams()
    return p.c_d * p.K * limit_ma * math.sqrt(p.P_s / p.rho)


def period_rows(table: dict) -> list:
    return [[f"{h:g}", f"{s:g}", f"{e:.3g}", f"{sat:.2%}"] for h, (s, e, sat) in table.items()]


def best_by_n(st: Study, group: str, h: float) -> dict:
    """n -> (sigma, quiet RMSE) of the best non-saturating cell at period h."""
    out = {}
    for n in NS:
        ok = [r for r in st.group(group) if r.params["n"] == n and r.params["h"] == h
              and not r.get("diverged", False) and r.get("saturation") <= 0.01]
        if ok:
            b = min(ok, key=lambda r: r.get("rmse_quiet"))
            out[n] = (b.params["sigma"], b.get("rmse_quiet"))
    return out
