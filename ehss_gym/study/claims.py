"""The paper's claims C1-C7: one rule per claim, judged on one designated configuration.

Every verdict is read from the runs of ONE configuration (:data:`~.config.CLAIM_CONFIGS`: the paper's run with the
env's defaults for each n, at the claim's f_r; C7 on the held-out suite), never from the best of several settings.
The sweep cells are context only: :func:`context_verdicts` applies the same rule to every cell that holds the runs
it needs, and the report counts them ("5 of 9 cells"). Pure functions of records (unit-tested on synthetic data).

Runs are keyed ``(configuration name, n)``; the held-out suite maps task -> n -> the episodes' metrics dicts (in
episode order, the same episodes for every n).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ehss_gym.evaluation.scoring import class_log_ratio
from ehss_gym.evaluation.stats import bootstrap_ci
from ehss_gym.infra.fmt import fmt_axis
from ehss_gym.infra.fmt import fmt_num as _f

from .config import (
    C4_CLAIM,
    C4_TOL,
    C7_BOOT,
    C7_CONFIDENCE,
    CHATTER_STRONG,
    CHATTER_WINDOW,
    CLAIM_CONFIGS,
    EDGE_TOL,
    G_NOMINAL,
    NS,
    OSC_PAPER,
    OSC_RATIO,
    SLIGHT_TOL,
    SUPPRESS,
    TRACK_TOL,
)
from .rules import cells_of

VERDICTS = ("reproduced", "partly", "not reproduced")
V100, V60, V60U, POS = "velocity 100 Hz", "velocity 60 Hz", "velocity 60 Hz unlimited", "position"
HELDOUT = "held-out suite"


@dataclass
class ClaimResult:
    claim: str
    verdict: str  # one of VERDICTS
    evidence: str


def _ok(rec) -> bool:
    return rec is not None and not rec.get("diverged", False)


def _div_text(rec) -> str:
    return f"diverged at t={_f(rec.get('t_diverged'), '.4g')} s" if rec.get("diverged", False) else ""


def _missing(cid: str, runs: dict, keys) -> ClaimResult | None:
    """'not reproduced, runs missing' if a run the rule needs is absent."""
    if any(runs.get(k) is None for k in keys):
        return ClaimResult(cid, VERDICTS[2], "runs missing")
    return None


def claim_c1(runs: dict) -> ClaimResult:
    """C1: at 100 Hz, n = 2 and 4 track with only slight overshoots at the friction edges."""
    if (miss := _missing("C1", runs, [(V100, n) for n in (2, 4)])) is not None:
        return miss
    parts, track, slight = [], True, True
    for n in (2, 4):
        r = runs[(V100, n)]
        if not _ok(r):
            track = False
            parts.append(f"n={n}: {_div_text(r)}")
            continue
        tr = r.get("rmse_nominal") <= TRACK_TOL["velocity"]
        sl = (r.get("max_abs_e_friction") <= SLIGHT_TOL and r.get("peak_edge_dist") <= EDGE_TOL
              and math.isfinite(r.get("recovery_off")))
        track &= tr
        slight &= sl
        parts.append(f"n={n}: RMSE nominal {_f(r.get('rmse_nominal'))}, friction peak "
                     f"{_f(r.get('max_abs_e_friction'))} rad/s at {_f(r.get('peak_edge_dist'), '.2f')} s from an "
                     f"edge, recovery off {_f(r.get('recovery_off'))} s")
    verdict = VERDICTS[0] if track and slight else VERDICTS[1] if track else VERDICTS[2]
    return ClaimResult("C1", verdict, "; ".join(parts))


def claim_c2(runs: dict) -> ClaimResult:
    """C2: at 100 Hz, n = 6 oscillates after 8 s (~15 rad/s, ~18 rad/s after 10 s); n = 2, 4 do not."""
    if (miss := _missing("C2", runs, [(V100, n) for n in NS])) is not None:
        return miss
    r6 = runs[(V100, 6)]
    others = [runs[(V100, n)] for n in (2, 4)]
    if any(not _ok(o) for o in others):
        return ClaimResult("C2", VERDICTS[2], "n=2 or n=4 diverged: " + "; ".join(_div_text(o) for o in others))
    of = max(o.get("amp_fric_sus") for o in others)
    op = max(o.get("amp_post_sus") for o in others)
    if not _ok(r6):
        on = r6.get("t_fric_on", 8.0)
        after = r6.get("t_diverged") is not None and r6.get("t_diverged") >= on
        v = VERDICTS[1] if after else VERDICTS[2]
        return ClaimResult("C2", v, f"n=6 {_div_text(r6)} ({'after' if after else 'before'} friction onset) "
                                    f"while n=2, 4 stay bounded (sustained max|e| {_f(of)}, {_f(op)} rad/s)")
    a6f, a6p, a6pre = r6.get("amp_fric_sus"), r6.get("amp_post_sus"), r6.get("amp_pre")
    ev = (f"sustained max|e| in [on+0.5 s, off): n=6 {_f(a6f)} vs n=2/4 {_f(of)} rad/s; after off+0.5 s: "
          f"n=6 {_f(a6p)} vs {_f(op)} rad/s; n=6 before the friction {_f(a6pre)} rad/s (paper: ~15 and ~18 rad/s)")
    osc = (a6f >= OSC_RATIO * max(of, 1e-12) and a6p >= OSC_RATIO * max(op, 1e-12)
           and a6f >= OSC_RATIO * a6pre)
    if osc and a6f >= OSC_PAPER and a6p >= OSC_PAPER:
        return ClaimResult("C2", VERDICTS[0], ev)
    if osc:
        return ClaimResult("C2", VERDICTS[1], ev + "; n=6 oscillates but far below the paper's amplitude")
    return ClaimResult("C2", VERDICTS[2], ev)


def claim_c3(runs: dict) -> ClaimResult:
    """C3: at 60 Hz the n = 6 oscillation of 100 Hz is suppressed, leaving small chattering."""
    if (miss := _missing("C3", runs, [(V100, n) for n in NS] + [(V60, 6)])) is not None:
        return miss
    r100, r60 = runs[(V100, 6)], runs[(V60, 6)]
    premise = claim_c2(runs).verdict != VERDICTS[2]
    if not _ok(r60):
        return ClaimResult("C3", VERDICTS[2], f"n=6 at 60 Hz {_div_text(r60)}")
    tracks = r60.get("rmse_nominal") <= TRACK_TOL["velocity"] and r60.get("max_abs_e_friction") <= SLIGHT_TOL
    a60 = max(r60.get("amp_fric_sus"), r60.get("amp_post_sus"))
    if _ok(r100):
        a100 = max(r100.get("amp_fric_sus"), r100.get("amp_post_sus"))
        ev100 = f"n=6 sustained max|e| {_f(a100)} rad/s at 100 Hz"
    else:
        a100 = math.inf
        ev100 = f"n=6 at 100 Hz {_div_text(r100)}"
    ev = (f"{ev100} -> {_f(a60)} rad/s at 60 Hz; n=6 at 60 Hz RMSE nominal {_f(r60.get('rmse_nominal'))}, "
          f"friction peak {_f(r60.get('max_abs_e_friction'))} rad/s; C2's premise "
          f"{'holds' if premise else 'absent'}")
    if premise and tracks and a60 <= SUPPRESS * a100:
        return ClaimResult("C3", VERDICTS[0], ev)
    if tracks and not premise:
        return ClaimResult("C3", VERDICTS[1], ev + "; n=6 tracks at 60 Hz, but there is no 100 Hz oscillation to "
                                                   "suppress")
    return ClaimResult("C3", VERDICTS[2], ev)


def claim_c4(runs: dict) -> ClaimResult:
    """C4: peak control ~1e10, 1e13, 1e18 for n = 2, 4, 6 at 60 Hz without a current limit (Fig. 10)."""
    if (miss := _missing("C4", runs, [(V60U, n) for n in NS])) is not None:
        return miss
    peaks, parts = {}, []
    for n in NS:
        r = runs[(V60U, n)]
        p = r.get("peak_u")
        peaks[n] = p
        G = r.get("G_med")
        G = G if G and math.isfinite(G) else G_NOMINAL
        s_impl = (10.0 ** C4_CLAIM[n] / G) ** (1.0 / (n - 1))
        parts.append(f"n={n}: {_f(p, '.2e')} mA (paper 1e{C4_CLAIM[n]:.0f}, which needs |s/sigma| ~ "
                     f"{_f(s_impl, '.2g')}){' [' + _div_text(r) + ']' if r.get('diverged', False) else ''}")
    logs = {n: math.log10(p) if p > 0 else -math.inf for n, p in peaks.items()}
    within = all(abs(logs[n] - C4_CLAIM[n]) <= C4_TOL for n in NS)
    ordered = logs[2] < logs[4] < logs[6]
    ev = "; ".join(parts) + "; off by " + ", ".join(f"{logs[n] - C4_CLAIM[n]:+.1f}" for n in NS) + " decades"
    if ordered and within:
        return ClaimResult("C4", VERDICTS[0], ev)
    if ordered:
        return ClaimResult("C4", VERDICTS[1], ev + "; the ordering n=2 < 4 < 6 holds, the magnitudes do not")
    return ClaimResult("C4", VERDICTS[2], ev)


def ratio_text(r: float) -> str:
    """A ratio for the evidence: near 1 as 1 plus its deviation (so a difference of 1e-7 shows as one)."""
    if math.isfinite(r) and r != 1.0 and abs(r - 1.0) < 1e-3:
        return f"1{r - 1.0:+.1e}"
    return _f(r, ".3g")


def disturbance_figures(recs: dict) -> dict:
    """n -> the disturbance-class figure (the ruler's, :func:`ehss_gym.evaluation.scoring.class_log_ratio`: the
    geometric mean of the friction-window peak and IAE ratios) of each run against n = 2's on the same episode;
    inf for a diverged run (it lost the reference), NaN where undefined."""
    ref = recs.get(2)
    out = {}
    for n, r in recs.items():
        if not _ok(r):
            out[n] = math.inf
        elif not _ok(ref):
            out[n] = math.nan
        else:
            out[n] = math.exp(class_log_ratio(r.metrics, ref.metrics, "disturbance", r.params["task"]))
    return out


def _six_least_robust(q: dict) -> bool:
    """n = 6's disturbance figure is the largest of the three (strictly; a diverged n = 2 or 4 fails it)."""
    return all(math.isfinite(q[n]) for n in (2, 4)) and q[6] > max(q[2], q[4])


def claim_c5(runs: dict) -> ClaimResult:
    """C5: all three position controllers track, n = 6 the least robust."""
    if (miss := _missing("C5", runs, [(POS, n) for n in NS])) is not None:
        return miss
    rs = {n: runs[(POS, n)] for n in NS}
    track = all(_ok(r) and r.get("rmse_nominal") <= TRACK_TOL["position"] for r in rs.values())
    q = disturbance_figures(rs)
    worst6 = _six_least_robust(q)
    ev = "; ".join(f"n={n}: " + (_div_text(r) if not _ok(r) else
                                 f"RMSE nominal {_f(r.get('rmse_nominal'))} rad, friction peak "
                                 f"{_f(r.get('dst_peak'))} rad, IAE {_f(r.get('dst_iae'))} rad s, disturbance "
                                 f"figure {_f(q[n], '.3g')}") for n, r in rs.items())
    if all(math.isfinite(q[n]) for n in NS):
        ev += f"; n=6 over the larger of n=2, 4: {ratio_text(q[6] / max(q[2], q[4]))}"
    if track and worst6:
        return ClaimResult("C5", VERDICTS[0], ev)
    if track or worst6:
        return ClaimResult("C5", VERDICTS[1], ev + ("; n=6 is not the least robust" if track else
                                                    "; not all three track"))
    return ClaimResult("C5", VERDICTS[2], ev)


def claim_c6(runs: dict) -> ClaimResult:
    """C6: the position control signals chatter strongly."""
    if (miss := _missing("C6", runs, [(POS, n) for n in NS])) is not None:
        return miss
    ci = {n: runs[(POS, n)].get("chatter_index") for n in NS}
    if any(not math.isfinite(v) for v in ci.values()):
        return ClaimResult("C6", VERDICTS[2], "chatter index not measured (the runs are not logged at every "
                                              "control period)")
    strong = [n for n in NS if ci[n] >= CHATTER_STRONG]
    ev = "; ".join(f"n={n}: chatter index {_f(ci[n], '.3g')}" + (f" [{_div_text(runs[(POS, n)])}]"
                                                                  if not _ok(runs[(POS, n)]) else "") for n in NS)
    v = VERDICTS[0] if len(strong) == len(NS) else VERDICTS[1] if strong else VERDICTS[2]
    return ClaimResult("C6", v, ev)


def paired_disturbance(a: list, b: list, task: str, seed: int = 0) -> tuple[float, float, float, int]:
    """The disturbance-class figure of episodes ``a`` against ``b`` (paired by position: the same episodes of
    ``task``), with its bootstrap CI over episodes (:data:`~.config.C7_CONFIDENCE`).

    Returns:
        (figure, CI low, CI high, episodes used): the episodes where neither diverged and the class is defined;
        NaNs with fewer than 2.
    """
    logs = [class_log_ratio(ma, mb, "disturbance", task) for ma, mb in zip(a, b)
            if not ma["diverged"] and not mb["diverged"]]
    logs = np.array([v for v in logs if math.isfinite(v)])
    if logs.size < 2:
        return math.nan, math.nan, math.nan, int(logs.size)
    lo, hi = bootstrap_ci(logs, "mean", "episodes", C7_BOOT, C7_CONFIDENCE, seed=seed)
    return math.exp(float(logs.mean())), math.exp(lo), math.exp(hi), int(logs.size)


def claim_c7(heldout: dict) -> ClaimResult:
    """C7: n = 2 and 4 are the best and most robust under friction: on the held-out suite of each task, their
    disturbance-class figures against n = 6's are both below 1 with CIs that exclude 1."""
    tasks = [t for t, by_n in heldout.items() if all(by_n.get(n) for n in NS)]
    if not tasks:
        return ClaimResult("C7", VERDICTS[2], "runs missing")
    holds, parts = [], []
    for task in tasks:
        by_n = heldout[task]
        ok, txt = True, []
        for k, n in enumerate((2, 4)):
            g, lo, hi, used = paired_disturbance(by_n[n], by_n[6], task, seed=k)
            ok &= hi < 1.0  # NaN compares False: an undefined figure does not hold
            txt.append(f"n={n}/n=6 {ratio_text(g)} [{ratio_text(lo)}, {ratio_text(hi)}]")
        div = "/".join(str(sum(1 for m in by_n[n] if m["diverged"])) for n in NS)
        parts.append(f"{task}: " + ", ".join(txt) + f" ({len(by_n[6])} episodes; diverged n=2/4/6: {div})")
        holds.append(ok)
    v = VERDICTS[0] if all(holds) else VERDICTS[1] if any(holds) else VERDICTS[2]
    return ClaimResult("C7", v, "; ".join(parts))


def _cell_c7(runs: dict) -> ClaimResult:
    """C7's rule on one sweep cell (context): n = 6's disturbance figure the largest on each configuration the cell
    holds (one episode per configuration: no CI)."""
    cfgs = sorted({c for c, n in runs if all((c, k) in runs for k in NS)})
    holds = [_six_least_robust(disturbance_figures({n: runs[(c, n)] for n in NS})) for c in cfgs]
    v = VERDICTS[0] if holds and all(holds) else VERDICTS[1] if any(holds) else VERDICTS[2]
    return ClaimResult("C7", v, f"n=6 the largest disturbance figure on {sum(holds)} of {len(cfgs)} configurations")


@dataclass(frozen=True)
class Claim:
    """One claim: what the paper says, the rule (text), the configuration it is judged on, and the rule's function."""

    paper: str
    rule: str
    config: str  # a name of CLAIM_CONFIGS, or HELDOUT
    judge: Callable
    needs: tuple  # (configuration, n) runs the rule reads (sweep cells without them are not counted)


CLAIMS: dict[str, Claim] = {
    "C1": Claim("At 100 Hz, n = 2 and 4 track with only slight overshoots at the friction edges",
                f"n = 2 and 4 both track (nominal RMSE <= {TRACK_TOL['velocity']:g}) -> at least partly; and both "
                f"friction peaks <= {SLIGHT_TOL:g} within {EDGE_TOL:g} s of an edge, recovered after the off edge "
                "-> reproduced", V100, claim_c1, tuple((V100, n) for n in (2, 4))),
    "C2": Claim("At 100 Hz, n = 6 oscillates after 8 s (~15 rad/s, then ~18 rad/s after 10 s)",
                f"n = 6's sustained max |e| during and after the friction >= {OSC_RATIO:g}x n = 2/4's and >= "
                f"{OSC_RATIO:g}x its own before the friction -> partly; also >= {OSC_PAPER:g} rad/s (about the "
                "paper's) -> reproduced; n = 6 diverging after the onset -> partly", V100, claim_c2,
                tuple((V100, n) for n in NS)),
    "C3": Claim("At 60 Hz the n = 6 oscillation is suppressed, leaving small chattering",
                f"C2's premise holds, n = 6 tracks at 60 Hz (nominal RMSE <= {TRACK_TOL['velocity']:g}, friction "
                f"peak <= {SLIGHT_TOL:g}) and its sustained error <= {SUPPRESS:g}x its 100 Hz value -> reproduced; "
                "the premise absent but n = 6 tracks at 60 Hz -> partly", V60, claim_c3,
                tuple((V100, n) for n in NS) + ((V60, 6),)),
    "C4": Claim("Peak control ~1e10, 1e13, 1e18 for n = 2, 4, 6 at 60 Hz",
                f"peak commanded current ordered n = 2 < 4 < 6 -> partly; and each within {C4_TOL:g} decade of "
                "the paper's -> reproduced", V60U, claim_c4, tuple((V60U, n) for n in NS)),
    "C5": Claim("All three position controllers track; n = 6 the least robust",
                f"all three track (nominal RMSE <= {TRACK_TOL['position']:g} rad) and n = 6's disturbance-class "
                "figure (friction-window peak and IAE, the ruler's) is the largest of the three -> reproduced; "
                "one of the two -> partly", POS, claim_c5, tuple((POS, n) for n in NS)),
    "C6": Claim("The position control signals chatter strongly",
                f"chatter index RMS(u - its {CHATTER_WINDOW * 1e3:g} ms moving average) / RMS(u) of the applied "
                f"current over the run >= {CHATTER_STRONG:g} for all three n -> reproduced; for some -> partly",
                POS, claim_c6, tuple((POS, n) for n in NS)),
    "C7": Claim("n = 2 and 4 are best and most robust under friction",
                "on the held-out suite, n = 2's and n = 4's disturbance-class figures against n = 6's are both "
                f"below 1 with {C7_CONFIDENCE:.0%} paired bootstrap CIs that exclude 1, in both tasks -> "
                "reproduced; in one task -> partly", HELDOUT, claim_c7, ()),
}


def judge_claims(runs: dict, heldout: dict) -> dict[str, ClaimResult]:
    """Every claim's verdict on its designated configuration.

    Args:
        runs: (configuration name, n) -> Record-like (with .get and .metrics) of the designated runs.
        heldout: task -> n -> the held-out episodes' metrics dicts (C7).
    """
    return {cid: c.judge(heldout if c.config == HELDOUT else runs) for cid, c in CLAIMS.items()}


def config_of(task: str, fr: float, limit) -> str | None:
    """The claim configuration a run of (task, f_r, current limit) stands for in the context counts (a sweep cell
    at any finite limit stands for the 10 mA configurations, an unlimited one for the unlimited), or None."""
    for name, (t, f, lim) in CLAIM_CONFIGS.items():
        if t == task and (f is None or f == fr) and (lim is None) == (limit is None):
            return name
    return None


def runs_of_records(records) -> dict:
    """(configuration name, n) -> record for records of one cell or set (runs no configuration stands for are
    left out)."""
    out = {}
    for r in records:
        c = config_of(r.params["task"], r.params["fr"], r.params["limit"])
        if c is not None:
            out[(c, r.params["n"])] = r
    return out


def claims_on_cell(runs: dict) -> dict[str, ClaimResult]:
    """The claims a partial set of runs (one sweep cell or paper set) can test, each by its own rule (C7 by its
    single-episode form :func:`_cell_c7`); context for the designated verdicts, never a verdict."""
    out = {}
    for cid, c in CLAIMS.items():
        if c.config == HELDOUT:
            if any(all((cfg, n) in runs for n in NS) for cfg, _ in runs):
                out[cid] = _cell_c7(runs)
        elif all(k in runs for k in c.needs):
            res = c.judge(runs)
            if res.evidence.startswith("chatter index not measured"):
                continue
            out[cid] = res
    return out


def context_verdicts(records: dict) -> dict[str, list[tuple[str, ClaimResult]]]:
    """Every claim's rule on every sweep cell that holds its runs (5 s phase-matched runs): claim -> [(cell label,
    result)]. Context only: the verdict is the designated configuration's."""
    out: dict[str, list] = {}
    specs = (("sigma_period", "sigma", "h", "h"), ("sigma_limit", "sigma", "limit", "limit"),
             ("position_sigma", "sigma", None, None))
    for g, row, col, cname in specs:
        for key, cell in cells_of(records.get(g, []), row, col).items():
            r0 = next(iter(cell.values()))
            lab = (f"{g}: sigma={fmt_axis(key[0])}" + (f", {cname}={fmt_axis(key[1])}" if col else "")
                   + f" (h={r0.params['h']:g} s)")
            for cid, res in claims_on_cell(runs_of_records(cell.values())).items():
                out.setdefault(cid, []).append((lab, res))
    # sigma x f_r: one set per sigma holds every f_r, so C3 (60 Hz against 100 Hz) can be tested
    by_sigma: dict = {}
    for r in records.get("sigma_fr", []):
        by_sigma.setdefault(r.params["sigma"], []).append(r)
    for sg, recs in sorted(by_sigma.items()):
        lab = f"sigma_fr: sigma={fmt_axis(sg)}, f_r 60 and 100 Hz (h={recs[0].params['h']:g} s)"
        for cid, res in claims_on_cell(runs_of_records(recs)).items():
            out.setdefault(cid, []).append((lab, res))
    return out
