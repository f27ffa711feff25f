"""Scoring: the primary score of an episode, per-episode scores of an evaluation, and its summaries.

**Primary score** (lower is better; the score residual PPO must beat), per episode::

    score = 0.5 * RMSE / RMSE_ref + 0.5 * TV / TV_ref        (capped at SCORE_CAP; divergence = SCORE_CAP)

with TV the control total variation per second (chattering index) and ``_ref`` the reference law
:data:`~ehss_gym.evaluation.specs.REFERENCE_POLICY` (the CLF law with n = 2 at the env's defaults) on the same
scenario. The reference scores exactly 1 on every episode; 0.8 means 20 % better on the equal-weight mix of
tracking and chattering. See :func:`primary_score`.

:func:`summarize` gives, per (suite, task, policy), the score statistics of :mod:`ehss_gym.evaluation.stats`
(mean and IQM with bootstrap CIs, probability of improvement over the best CLF) and the mean metrics, and, per
learned policy, its comparison with the CLF laws at its own controller settings.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from . import stats
from .specs import CLF_RE, REFERENCE_POLICY, PolicySpec, controller_settings
from .suites import SUITES, TASKS, EvalConfig

SCORE_CAP = 10.0  # [-] score of a diverged episode, and the most any episode can score
W_TRACK = 0.5  # weight of the RMSE ratio in the primary score
W_CHATTER = 0.5  # weight of the control-TV ratio
RMSE_FLOOR = 1e-12  # [output unit] guards a division by an exactly zero reference RMSE
TV_FLOOR = 1e-9  # [mA/s]

# (key, label, unit ("U" = output unit), definition) of every reported metric; keys of metrics.summarize_acc
METRICS = (
    ("rmse", "RMSE", "U", "sqrt(mean e^2) over all control steps, e = y - y_d"),
    ("rmse_nominal", "RMSE outside friction", "U", "the same over the steps with no friction event active"),
    ("iae", "IAE", "U*s", "sum |e| h over the control steps (h the control period)"),
    ("itae", "ITAE", "U*s^2", "sum t |e| h"),
    ("max_abs_e", "max |e|", "U", "largest |e| of the episode"),
    ("max_abs_e_friction", "max |e| in friction", "U", "largest |e| while a friction event is active"),
    ("recovery_on", "recovery on", "s",
     "time from the first friction switch-on until |e| enters and stays in 2x the largest |e| of the second "
     "before it (error sampled once per agent step); inf = never"),
    ("recovery_off", "recovery off", "s", "the same after that event switches off"),
    ("tv_u_rate", "control TV", "mA/s",
     "chattering index: sum |u_k - u_{k-1}| of the applied current over the control steps, per second"),
    ("rms_u", "RMS current", "mA", "sqrt(mean u^2) of the applied current"),
    ("peak_u_applied", "peak current", "mA", "largest |u| applied (after the current limit)"),
    ("saturation", "saturation", "-", "share of control steps on which the current limit clipped the command"),
    ("v_decrease", "V decrease", "-", "share of control steps on which the CLF value V = (s/sigma)^n/n fell"),
    ("diverged", "divergence rate", "-",
     "share of episodes stopped by a non-finite value, |x2| > omega_max or |x3| > 1.5 P_s"),
    ("lost_track", "lost-track rate", "-",
     "share of episodes that lost track without diverging: past the start-up (0.2 s), the RMS of e over a "
     "0.1 s sliding window exceeded the reference's amplitude (a saturated oscillation, for instance)"),
)
METRIC_KEYS = tuple(m[0] for m in METRICS)
RATE_KEYS = {"diverged": "divergence_rate", "lost_track": "lost_track_rate"}  # per-episode flag -> summary rate
RATIOS = (("rmse", "rmse_ratio"), ("tv_u_rate", "tv_ratio"), ("max_abs_e_friction", "friction_peak_ratio"))


def primary_score(rmse: float, tv_rate: float, rmse_ref: float, tv_ref: float, diverged: bool) -> float:
    """The primary score of one episode (lower is better; the reference law scores 1).

    ``0.5 * RMSE / RMSE_ref + 0.5 * TV / TV_ref``, capped at :data:`SCORE_CAP`; a diverged episode
    scores :data:`SCORE_CAP`.

    Args:
        rmse: the episode's tracking RMSE [output unit].
        tv_rate: its control total variation per second [mA/s].
        rmse_ref: the reference law's RMSE on the same scenario [output unit].
        tv_ref: the reference law's control TV per second on it [mA/s].
        diverged: the episode diverged.
    """
    if diverged or not (math.isfinite(rmse) and math.isfinite(tv_rate)):
        return SCORE_CAP
    s = W_TRACK * rmse / max(rmse_ref, RMSE_FLOOR) + W_CHATTER * tv_rate / max(tv_ref, TV_FLOOR)
    return float(min(s, SCORE_CAP))


def score_rows(rows: list) -> None:
    """Add ``score`` and ``score_normaliser`` to every per-episode row, normalised by the reference law on the same
    episode (by its suite median where the reference itself diverged).

    Raises:
        RuntimeError: an episode the reference law was not run on.
    """
    ref = {}
    for r in rows:
        if r["policy"] == REFERENCE_POLICY:
            ref[(r["suite"], r["task"], r["episode"])] = r
    valid = {}
    for (suite, task, _), r in ref.items():
        if not r["diverged"]:
            valid.setdefault((suite, task), []).append((r["rmse"], r["tv_u_rate"]))
    for r in rows:
        k = (r["suite"], r["task"], r["episode"])
        rr = ref.get(k)
        if rr is None:
            raise RuntimeError(f"no {REFERENCE_POLICY} result for {k}; the reference law must be evaluated")
        if rr["diverged"]:  # fall back on the suite median of the reference
            pool = valid.get((r["suite"], r["task"]))
            rm, tv = (np.median([p[0] for p in pool]), np.median([p[1] for p in pool])) if pool else (1.0, 1.0)
            r["score_normaliser"] = "suite median (reference diverged)"
        else:
            rm, tv = rr["rmse"], rr["tv_u_rate"]
            r["score_normaliser"] = "same episode"
        r["score"] = primary_score(r["rmse"], r["tv_u_rate"], rm, tv, r["diverged"])


def matrix(rows: list, policy: str, suite: str, task: str, key: str = "score", episodes: list | None = None):
    """The (runs, episodes) matrix of ``key`` for one policy, suite and task.

    Args:
        rows: per-episode rows.
        policy: the policy's name.
        suite: the suite.
        task: the task.
        key: the row field.
        episodes: episode ids in column order (default: their order in ``rows``).

    Returns:
        (matrix or None if the policy has no such rows, the episode ids of its columns).
    """
    sel = [r for r in rows if r["policy"] == policy and r["suite"] == suite and r["task"] == task]
    if not sel:
        return None, []
    eps = episodes or sorted({r["episode"] for r in sel}, key=lambda e: next(
        i for i, r in enumerate(sel) if r["episode"] == e))
    runs = sorted({r["run"] for r in sel})
    idx = {(r["run"], r["episode"]): r for r in sel}
    m = np.array([[float(idx[(ru, e)][key]) for e in eps] for ru in runs])
    return m, eps


def _scores_against(rows: list, policy: str, suite: str, task: str, episodes: list, ref: str) -> np.ndarray:
    """(runs, episodes) primary scores of ``policy`` normalised by the law ``ref`` on the same episodes (the
    suite median of ``ref`` where ``ref`` diverged), instead of by :data:`REFERENCE_POLICY`."""
    ref_rm = matrix(rows, ref, suite, task, "rmse", episodes)[0][0]
    ref_tv = matrix(rows, ref, suite, task, "tv_u_rate", episodes)[0][0]
    ref_div = matrix(rows, ref, suite, task, "diverged", episodes)[0][0].astype(bool)
    if ref_div.any():
        ok = ~ref_div
        ref_rm = np.where(ref_div, np.median(ref_rm[ok]) if ok.any() else 1.0, ref_rm)
        ref_tv = np.where(ref_div, np.median(ref_tv[ok]) if ok.any() else 1.0, ref_tv)
    rm = matrix(rows, policy, suite, task, "rmse", episodes)[0]
    tv = matrix(rows, policy, suite, task, "tv_u_rate", episodes)[0]
    div = matrix(rows, policy, suite, task, "diverged", episodes)[0].astype(bool)
    return np.array([[primary_score(rm[i, j], tv[i, j], ref_rm[j], ref_tv[j], div[i, j]) for j in range(rm.shape[1])]
                     for i in range(rm.shape[0])])


def _finite_mean(v) -> float:
    """Mean of the finite values of ``v`` (NaN if none)."""
    v = np.asarray(v, dtype=np.float64)
    v = v[np.isfinite(v)]
    return float(v.mean()) if v.size else math.nan


def _mean_metrics(sel: list) -> dict:
    """Means of every metric over the non-diverged rows ``sel`` (recovery: plus the count that never recovered),
    and the divergence and lost-track rates over all of them."""
    d = {}
    ok = [r for r in sel if not r["diverged"]]
    for key in METRIC_KEYS:
        if key in ("diverged", "lost_track"):
            d[RATE_KEYS[key]] = float(np.mean([bool(r[key]) for r in sel]))
        elif key.startswith("recovery"):
            vals = [r[key] for r in ok if not math.isnan(r[key])]
            d[key] = _finite_mean(vals)
            d[key + "_never"] = int(sum(1 for v in vals if math.isinf(v)))
        else:
            d[key] = _finite_mean([r[key] for r in ok])
    return d


def _score_statistics(m: np.ndarray, k: int, cfg: EvalConfig) -> dict:
    """Mean, IQM and median of one policy's (runs, episodes) score matrix ``m`` with bootstrap CIs (over episodes;
    with several runs also over seeds and both); ``k`` = its place in the block (the bootstrap seeds differ)."""
    s = stats.summarize_scores(m, n_boot=cfg.n_boot, seed=cfg.seed + 101 * k)
    d = {"n_runs": s["n_runs"], "n_episodes": s["n_episodes"],
         "score_mean": s["mean"], "score_mean_lo": s["mean_ci"][0], "score_mean_hi": s["mean_ci"][1],
         "score_iqm": s["iqm"], "score_iqm_lo": s["iqm_ci"][0], "score_iqm_hi": s["iqm_ci"][1],
         "score_median": s["median"]}
    if s["n_runs"] > 1:
        d["score_mean_lo_seeds"], d["score_mean_hi_seeds"] = s["mean_ci_seeds"]
        d["score_mean_lo_both"], d["score_mean_hi_both"] = s["mean_ci_both"]
    return d


def _block_summary(rows: list, present: list, mats: dict, suite: str, task: str, cfg: EvalConfig) -> list:
    """The ranked summary rows of one (suite, task) block."""
    clfs = [n for n in present if CLF_RE.match(n)]
    best = min(clfs, key=lambda n: (mats[n].mean(), n)) if clfs else None
    block = []
    for k, n in enumerate(present):
        m = mats[n]
        d = {"suite": suite, "task": task, "policy": n, "rank": 0}
        d.update(_score_statistics(m, k, cfg))
        d["best_clf"] = best or ""
        if best is not None and n != best:
            p, lo, hi = stats.probability_of_improvement_ci(m, mats[best], n_boot=cfg.n_boot, seed=cfg.seed + 7 + k)
            d["poi_vs_best_clf"], d["poi_lo"], d["poi_hi"] = p, lo, hi
        else:
            d["poi_vs_best_clf"] = d["poi_lo"] = d["poi_hi"] = math.nan
        d.update(_mean_metrics([r for r in rows if r["policy"] == n and r["suite"] == suite and r["task"] == task]))
        block.append(d)
    order = sorted(block, key=lambda d: (d["score_mean"], d["policy"]))
    for rank, d in enumerate(order, 1):
        d["rank"] = rank
    return order


def _comparison(rows: list, spec: PolicySpec, specs: Sequence[PolicySpec], mats: dict, eps: list, suite: str,
                task: str, cfg: EvalConfig) -> dict | None:
    """A learned policy against the best CLF n = 2/4/6 at its own controller settings and its base law (None if
    no CLF at those settings was run)."""
    n = spec.name
    mine = controller_settings(spec.env_kwargs, task)
    same = [s for s in specs if s.kind == "clf" and s.name in mats and int(s.env_kwargs["n"]) in (2, 4, 6)
            and controller_settings(s.env_kwargs, task) == mine]
    if not same:
        return None
    # Scores against the n = 2 law *at these settings* (the reference law itself when the settings are the
    # defaults): a same-settings comparison must not be weighted by a loop the policy does not act in (a smoothed
    # law's tiny TV on noise-free episodes, say).
    ref_same = next((s.name for s in same if int(s.env_kwargs["n"]) == 2), REFERENCE_POLICY)
    sm = {x: (mats[x] if ref_same == REFERENCE_POLICY else _scores_against(rows, x, suite, task, eps, ref_same))
          for x in [n] + [s.name for s in same]}
    best_same = min(same, key=lambda s: (sm[s.name].mean(), s.name))
    m = sm[n]
    imp, lo, hi = stats.relative_improvement_ci(m, sm[best_same.name], n_boot=cfg.n_boot, seed=cfg.seed + 3)
    p, plo, phi = stats.probability_of_improvement_ci(m, sm[best_same.name], n_boot=cfg.n_boot, seed=cfg.seed + 5)
    c = {"suite": suite, "task": task, "policy": n, "n_runs": m.shape[0], "best_clf": best_same.name,
         "score_reference": ref_same, "score_mean": float(m.mean()),
         "best_clf_score_mean": float(sm[best_same.name].mean()),
         "improvement": imp, "improvement_lo": lo, "improvement_hi": hi, "poi": p, "poi_lo": plo, "poi_hi": phi}
    base = best_same.name
    if spec.env_kwargs.get("mode", "residual") == "residual":
        nn = int(spec.env_kwargs.get("n", 2))
        base = next((s.name for s in same if int(s.env_kwargs["n"]) == nn), best_same.name)
    c["base_law"] = base
    for key, label in RATIOS:
        a = matrix(rows, n, suite, task, key, eps)[0]
        b = matrix(rows, base, suite, task, key, eps)[0]
        good = np.isfinite(a).all(axis=0) & np.isfinite(b).all(axis=0)
        c[label] = float(a[:, good].mean() / b[:, good].mean()) if good.any() else math.nan
    return c


def summarize(rows: list, specs: Sequence[PolicySpec], cfg: EvalConfig) -> tuple[list, list]:
    """Per (suite, task, policy): score statistics, PoI against the best CLF and mean metrics; comparisons.

    Args:
        rows: scored per-episode rows (:func:`score_rows`).
        specs: the evaluated policies (order = order within a block before ranking).
        cfg: bootstrap sizes and seed.

    Returns:
        (summary rows in suite, task, rank order; comparison rows of the learned policies).
    """
    summary, comparisons = [], []
    names = [s.name for s in specs]
    for suite in SUITES:
        for task in TASKS:
            present = [n for n in names if any(r["policy"] == n and r["suite"] == suite and r["task"] == task
                                               for r in rows)]
            if not present:
                continue
            _, eps = matrix(rows, REFERENCE_POLICY, suite, task)
            mats = {n: matrix(rows, n, suite, task, episodes=eps)[0] for n in present}
            summary += _block_summary(rows, present, mats, suite, task, cfg)
            for spec in specs:
                if spec.name in present and spec.learned:
                    c = _comparison(rows, spec, specs, mats, eps, suite, task, cfg)
                    if c is not None:
                        comparisons.append(c)
    return summary, comparisons


__all__ = ["SCORE_CAP", "METRICS", "METRIC_KEYS", "primary_score", "score_rows", "matrix", "summarize"]
