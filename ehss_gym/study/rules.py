"""Where n matters, and the rules that recommend the env's defaults (pure functions of records; unit-tested)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from .config import MATTERS, REC_ABS, SAT_MATTERS
from .records import Record

MAP_METRICS = (("rmse_quiet", "quiet RMSE", True), ("max_abs_e_friction", "peak |e| in friction", True),
               ("recovery_on", "recovery after on [s]", True), ("tv_u_rate", "chattering: TV rate [mA/s]", True),
               ("saturation", "saturation fraction", False))


def n_effect(cell: dict) -> dict:
    """How much n changes each outcome in one sweep cell.

    Args:
        cell: n -> Record-like (with .get).

    Returns:
        metric -> (spread, matters): spread is max/min over n (saturation: max - min;
        recovery: max - min [s]); matters as defined by MATTERS, SAT_MATTERS, REC_ABS;
        plus "diverged" -> (number of n that diverged, differs).
    """
    out = {}
    recs = [cell[n] for n in sorted(cell)]
    div = [bool(r.get("diverged", False)) for r in recs]
    out["diverged"] = (sum(div), any(div) and not all(div))
    live = [r for r in recs if not r.get("diverged", False)]
    for key, _, _ in MAP_METRICS:
        vals = [r.get(key) for r in live]
        vals = [v for v in vals if v is not None and not (isinstance(v, float) and math.isnan(v))]
        if len(vals) < 2:
            out[key] = (math.nan, out["diverged"][1])
            continue
        if key == "saturation":
            sp = max(vals) - min(vals)
            out[key] = (sp, sp >= SAT_MATTERS)
        elif key == "recovery_on":
            fin = [math.isfinite(v) for v in vals]
            if any(fin) and not all(fin):
                out[key] = (math.inf, True)
            elif not any(fin):
                out[key] = (0.0, False)
            else:
                sp = max(vals) - min(vals)
                out[key] = (sp, sp >= REC_ABS and max(vals) >= MATTERS * max(min(vals), 1e-12))
        else:
            lo, hi = min(vals), max(vals)
            sp = hi / lo if lo > 0 else (math.inf if hi > 0 else 1.0)
            out[key] = (sp, sp >= MATTERS)
    return out


def n_matters(cell: dict, keys=("rmse_quiet", "max_abs_e_friction", "recovery_on", "tv_u_rate")) -> bool:
    """True if n changes the outcome of the cell (a listed metric, or divergence)."""
    eff = n_effect(cell)
    return eff["diverged"][1] or any(eff[k][1] for k in keys)


def cells_of(records: Sequence[Record], row: str, col: str | None) -> dict:
    """(row value, col value) -> {n: record}."""
    cells: dict = {}
    for r in records:
        key = (r.params[row], r.params[col] if col else None)
        cells.setdefault(key, {})[r.params["n"]] = r
    return cells


def choose_period_sigma(records: Sequence[Record], n: int = 2, max_sat: float = 0.01, tol: float = 2.0):
    """Control period and sigma for the env.

    Among runs with power factor ``n`` that did not diverge and saturate on at most
    ``max_sat`` of steps, take the best sigma (lowest quiet RMSE, ``rmse_quiet``: the tracking error away
    from the start-up and the friction transients) at each period;
    choose the largest period whose best RMSE is within ``tol`` times the best over
    all periods (a longer period makes the env cheaper).

    Returns:
        (h, sigma, table) with table: h -> (sigma, rmse_quiet, saturation) of the best cell.
    """
    best: dict[float, Record] = {}
    for r in records:
        if r.params["n"] != n or r.get("diverged", False) or r.get("saturation") > max_sat:
            continue
        h = r.params["h"]
        if h not in best or _quiet(r) < _quiet(best[h]):
            best[h] = r
    if not best:
        raise ValueError(f"no run with n={n} stays below saturation {max_sat} without diverging")
    floor = min(_quiet(r) for r in best.values())
    ok = [h for h, r in best.items() if _quiet(r) <= tol * floor]
    h = max(ok)
    table = {k: (r.params["sigma"], _quiet(r), r.get("saturation")) for k, r in sorted(best.items())}
    return h, best[h].params["sigma"], table


def _quiet(r) -> float:
    """The quiet RMSE of a record, +inf where undefined (no quiet step): such a run never wins a comparison."""
    v = r.get("rmse_quiet")
    return v if v is not None and math.isfinite(v) else math.inf


def is_lost(r, lost_rms: float) -> bool:
    """An episode has lost track: it diverged, or the RMS error of some 0.1 s window after the first 0.2 s
    exceeds ``lost_rms`` [output unit] (``window_rms_max``)."""
    return bool(r.get("diverged", False)) or not r.get("window_rms_max") <= lost_rms


def lost_table(records: Sequence[Record], keys: Sequence[str], lost_rms: float) -> dict:
    """Records grouped by the values of ``keys`` (one key: the value; several: a tuple).

    Returns:
        key -> (lost share, mean RMSE, median RMSE, mean saturation, episodes).
    """
    groups: dict = {}
    for r in records:
        k = tuple(r.params[x] for x in keys)
        groups.setdefault(k if len(keys) > 1 else k[0], []).append(r)
    table = {}
    for k in sorted(groups, key=lambda v: tuple(math.inf if x is None else x for x in (v if len(keys) > 1 else (v,)))):
        rs = groups[k]
        rmse = [r.get("rmse") for r in rs]
        table[k] = (float(np.mean([is_lost(r, lost_rms) for r in rs])), float(np.mean(rmse)), float(np.median(rmse)),
                    float(np.mean([r.get("saturation") for r in rs])), len(rs))
    return table


def choose_robust(records: Sequence[Record], key: str, start: float, lost_rms: float, max_lost: float):
    """The smallest value >= ``start`` of setting ``key`` ("h" or "limit") at which the law loses track on at
    most ``max_lost`` of the randomised episodes (:func:`is_lost`). Both a longer control period and a larger
    current limit cost something (a slower loop, a bigger valve), so the smallest passing value is taken.

    Returns:
        (value, rule_met, table) with table: value -> (lost share, mean RMSE, median RMSE, mean saturation,
        episodes); if no value >= start qualifies, value = start and rule_met = False.
    """
    table = lost_table(records, (key,), lost_rms)
    ok = [h for h, row in table.items() if h >= start and row[0] <= max_lost]
    if not ok:
        return start, False, table
    return min(ok), True, table


def choose_robust_cell(records: Sequence[Record], start: float, lost_rms: float, max_lost: float):
    """Control period, f_r and sigma that keep the lost-track share of the randomised episodes <= ``max_lost``.

    The shortest period h >= ``start`` at which some (f_r, sigma) cell passes (as :func:`choose_robust`:
    a longer period is a slower loop); among that period's passing cells, the one with the lowest median
    RMSE over the episodes. If no cell passes anywhere, the cell with the lowest lost share (then the lowest
    median RMSE) at ``start`` and rule_met = False.

    Returns:
        (h, f_r, sigma, rule_met, table) with table: (h, f_r, sigma) -> (lost share, mean RMSE, median RMSE,
        mean saturation, episodes).
    """
    table = lost_table(records, ("h", "fr", "sigma"), lost_rms)
    if not table:
        raise ValueError("no randomised-scenario runs to choose from")
    periods = sorted({k[0] for k in table if k[0] >= start})
    for h in periods:
        ok = [k for k, row in table.items() if k[0] == h and row[0] <= max_lost]
        if ok:
            best = min(ok, key=lambda k: (table[k][2], k))
            return best[0], best[1], best[2], True, table
    at = [k for k in table if k[0] == (periods[0] if periods else min(k[0] for k in table))]
    best = min(at, key=lambda k: (table[k][0], table[k][2], k))
    return best[0], best[1], best[2], False, table


def attraction_bounds(records: Sequence[Record], lost_rms: float) -> dict:
    """Start-up probe: the largest initial error a loop recovers from, with every smaller one recovered too.

    Args:
        records: runs from rest towards a constant reference (params "fr", "sigma", "estimator"; feature
            "r0" = the reference at t = 0, i.e. the initial error [output unit]).
        lost_rms: the lost-track threshold of :func:`is_lost`.

    Returns:
        (f_r, sigma, estimator) -> (largest recovered |r0|, smallest lost |r0| or inf); 0 if even the smallest
        tried is lost.
    """
    groups: dict = {}
    for r in records:
        groups.setdefault((r.params["fr"], r.params["sigma"], r.params["estimator"]), []).append(r)
    out = {}
    for k, rs in sorted(groups.items()):
        ok_max, first_lost = 0.0, math.inf
        for r in sorted(rs, key=lambda x: abs(x.features["r0"])):
            if is_lost(r, lost_rms):
                first_lost = abs(r.features["r0"])
                break
            ok_max = abs(r.features["r0"])
        out[k] = (ok_max, first_lost)
    return out


def power_law_slope(x: Sequence[float], y: Sequence[float]) -> float:
    """Least-squares slope of log y against log x over the finite, positive pairs (NaN if fewer than 2)."""
    pts = [(a, b) for a, b in zip(x, y) if a > 0 and b > 0 and math.isfinite(a) and math.isfinite(b)]
    if len(pts) < 2:
        return math.nan
    lx, ly = np.log([p[0] for p in pts]), np.log([p[1] for p in pts])
    return float(np.polyfit(lx, ly, 1)[0])


def admissible_sigmas(records: Sequence[Record], n: int = 2, max_sat: float = 0.01) -> list:
    """The sigmas whose runs of power factor n neither diverged nor saturated on more than ``max_sat`` of steps."""
    return sorted({r.params["sigma"] for r in records if r.params["n"] == n and not r.get("diverged", False)
                   and r.get("saturation") <= max_sat})


def choose_sigma(records: Sequence[Record], n: int, max_sat: float = 0.01):
    """The sigma with the lowest quiet RMSE among non-diverged runs of power factor n with saturation <= max_sat."""
    ok = [r for r in records if r.params["n"] == n and not r.get("diverged", False) and r.get("saturation") <= max_sat]
    if not ok:
        return None
    return min(ok, key=lambda r: _quiet(r)).params["sigma"]


def least_saturating_sigma(records: Sequence[Record], n: int):
    """The sigma whose non-diverged run of power factor n saturates least (ties: lower quiet RMSE); None if none."""
    ok = [r for r in records if r.params["n"] == n and not r.get("diverged", False)]
    if not ok:
        return None
    return min(ok, key=lambda r: (round(r.get("saturation"), 3), _quiet(r))).params["sigma"]


def choose_substeps(records: Sequence[Record], rel_tol: float = 0.02) -> int:
    """Smallest substeps whose RMSE and friction peak are within rel_tol of the finest run's, for every n."""
    by_n: dict[int, dict[int, Record]] = {}
    for r in records:
        by_n.setdefault(r.params["n"], {})[r.params["substeps"]] = r
    levels = sorted({r.params["substeps"] for r in records})
    for ss in levels:
        good = True
        for runs in by_n.values():
            ref = runs[max(runs)]
            r = runs.get(ss)
            if r is None or r.get("diverged", False):
                good = False
                break
            for key in ("rmse_quiet", "max_abs_e_friction"):
                a, b = r.get(key), ref.get(key)
                if not abs(a - b) <= rel_tol * abs(b):
                    good = False
        if good:
            return ss
    return levels[-1]


def choose_limit(records: Sequence[Record], tol: float = 1.25, max_sat: float = 0.01):
    """Smallest finite current limit [mA] that keeps the law usable.

    The limit models the valve's rated current, so the smallest one is preferred
    (a smaller valve). A limit qualifies if its run did not diverge, recovered after
    both friction edges, saturated on at most ``max_sat`` of steps, and kept the
    quiet RMSE within ``tol`` times the reference's: the unlimited run (or, if
    that diverged, the best finite one). The friction-window peak is not part of
    the rule: a limit below the ~90 mA the unlimited law spends at a friction edge
    necessarily raises it (the report shows by how much). Returns None if no
    finite limit qualifies.
    """
    runs = {r.params["limit"]: r for r in records}
    ref = runs.get(None)
    finite = sorted(k for k in runs if k is not None)
    if ref is None or ref.get("diverged", False):
        live = [runs[k] for k in finite if not runs[k].get("diverged", False)]
        if not live:
            return None
        ref = min(live, key=lambda r: _quiet(r))
    for k in finite:
        r = runs[k]
        if r.get("diverged", False) or not (math.isfinite(r.get("recovery_on")) and
                                             math.isfinite(r.get("recovery_off"))):
            continue
        if _quiet(r) <= tol * _quiet(ref) and r.get("saturation") <= max_sat:
            return k
    return None


def choose_smoothing(records: Sequence[Record], tol: float = 1.1) -> float:
    """Width w with the lowest control TV among those whose RMSE and friction peak stay within tol of the plain law."""
    runs = {r.params["smoothing"]: r for r in records}
    plain = runs[0.0]
    ok = [w for w, r in runs.items() if not r.get("diverged", False)
          and _quiet(r) <= tol * _quiet(plain)
          and r.get("max_abs_e_friction") <= tol * plain.get("max_abs_e_friction")]
    return min(ok, key=lambda w: (runs[w].get("tv_u_rate"), w))
