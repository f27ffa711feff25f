"""Aggregate statistics of evaluation scores with bootstrap confidence intervals, in the manner of rliable.

Agarwal et al. (2021), "Deep RL at the edge of the statistical precipice" (the ``rliable`` library),
recommend reporting an aggregate with a bootstrap confidence interval rather than a bare mean, the
interquartile mean (IQM) as a robust aggregate, and the probability of improvement as a comparison.
This module implements those pieces with numpy only (seeded, deterministic).

Scores are arranged as a matrix ``(n_runs, n_tasks)``: a *run* is one training seed of a policy
(scripted policies have one run), a *task* is one evaluation episode (scenario). A 1-D array is one
run over its episodes.

- :func:`iqm`: mean of the middle 50 % of all scores (``scipy.stats.trim_mean(x, 0.25)`` on the
  flattened matrix: ``floor(0.25 N)`` values cut from each end).
- :func:`bootstrap_ci`: percentile bootstrap interval of an aggregate, resampling episodes
  (columns, with replacement), training seeds (rows), or both independently (a two-way bootstrap).
- :func:`probability_of_improvement`: P(X better than Y) as rliable defines it: per episode the
  Mann-Whitney statistic over pairs of runs (1 if X's run beats Y's, 1/2 on a tie), averaged over
  episodes. Its interval resamples episodes (paired: both policies see the same episodes) and, when
  a policy has several runs, runs within each episode (rliable's stratified bootstrap).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable

import numpy as np

STATS = ("mean", "iqm", "median")
OVER = ("episodes", "seeds", "both")


def _as_matrix(scores, name: str = "scores") -> np.ndarray:
    """Scores as a finite float (n_runs, n_tasks) matrix; 1-D input is one run."""
    a = np.asarray(scores, dtype=np.float64)
    if a.ndim == 1:
        a = a[None, :]
    if a.ndim != 2:
        raise ValueError(f"{name} must be 1-D (episodes) or 2-D (seeds x episodes), got shape {a.shape}")
    if a.size == 0:
        raise ValueError(f"{name} must hold at least one value, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite (map diverged episodes to a penalty score first)")
    return a


def _check_stat(stat: str) -> str:
    """``stat`` if it is one of :data:`STATS`, else ValueError."""
    if stat not in STATS:
        raise ValueError(f"stat must be one of {list(STATS)}, got {stat!r}")
    return stat


def iqm(scores) -> float:
    """Interquartile mean: the mean of the middle 50 % of all values (``floor(N/4)`` cut from each end).

    Equals ``scipy.stats.trim_mean(x.ravel(), 0.25)``, rliable's IQM.
    """
    x = np.sort(_as_matrix(scores).ravel())
    cut = int(math.floor(0.25 * x.size))
    return float(x[cut:x.size - cut].mean())


def aggregate(scores, stat: str = "mean") -> float:
    """``stat`` ("mean", "iqm" or "median") of all values of a scores array."""
    _check_stat(stat)
    a = _as_matrix(scores)
    if stat == "mean":
        return float(a.mean())
    if stat == "median":
        return float(np.median(a))
    return iqm(a)


def _batched(stat: str) -> Callable[[np.ndarray], np.ndarray]:
    """Aggregate over the last axis of a (n_boot, N) array, one value per row."""
    if stat == "mean":
        return lambda x: x.mean(axis=1)
    if stat == "median":
        return lambda x: np.median(x, axis=1)

    def _iqm(x):
        """Row-wise IQM: the mean of the middle 50 % (floor(0.25 n) values cut from each end)."""
        n = x.shape[1]
        cut = int(math.floor(0.25 * n))
        return np.sort(x, axis=1)[:, cut:n - cut].mean(axis=1)

    return _iqm


def _check_common(n_boot, confidence, seed):
    """ValueError unless n_boot >= 100, 0.5 <= confidence < 1 and seed >= 0 (integers where integers are meant)."""
    if isinstance(n_boot, bool) or not isinstance(n_boot, (int, np.integer)) or n_boot < 100:
        raise ValueError(f"n_boot must be an integer >= 100, got {n_boot!r}")
    if not isinstance(confidence, (int, float)) or not 0.5 <= confidence < 1.0:
        raise ValueError(f"confidence must be a number in [0.5, 1), got {confidence!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")


def _check_chunk(chunk) -> None:
    """ValueError unless ``chunk`` (replicates per vectorised batch) is an integer >= 1."""
    if isinstance(chunk, bool) or not isinstance(chunk, (int, np.integer)) or chunk < 1:
        raise ValueError(f"chunk must be an integer >= 1, got {chunk!r}")


def _resample_indices(rng: np.random.Generator, n_boot: int, n: int, resample: bool) -> np.ndarray:
    """(n_boot, n) indices drawn with replacement, or the identity in every replicate when not ``resample``."""
    if not resample:
        return np.broadcast_to(np.arange(n), (n_boot, n))
    return rng.integers(0, n, size=(n_boot, n))


def bootstrap_distribution(scores, stat: str = "mean", over: str = "episodes", n_boot: int = 2000,
                           seed: int = 0, chunk: int = 500) -> np.ndarray:
    """Bootstrap replicates of an aggregate.

    Args:
        scores: (n_runs, n_tasks) or (n_tasks,) finite values.
        stat: "mean", "iqm" or "median".
        over: "episodes" (resample columns), "seeds" (resample rows) or "both" (rows and columns
            independently, a two-way bootstrap).
        n_boot: number of replicates (>= 100).
        seed: RNG seed (>= 0); the same seed gives the same replicates.
        chunk: replicates drawn per vectorised batch (memory bound only; results do not depend on it
            for a fixed ``n_boot`` and ``seed`` because indices are drawn in the same order).

    Returns:
        (n_boot,) replicate values.
    """
    _check_stat(stat)
    if over not in OVER:
        raise ValueError(f"over must be one of {list(OVER)}, got {over!r}")
    _check_common(n_boot, 0.95, seed)
    _check_chunk(chunk)
    a = _as_matrix(scores)
    R, T = a.shape
    rng = np.random.default_rng(int(seed))
    agg = _batched(stat)
    rows_on = over in ("seeds", "both")
    cols_on = over in ("episodes", "both")
    # draw every index up front so the result does not depend on chunking
    ri = _resample_indices(rng, n_boot, R, rows_on)
    ci = _resample_indices(rng, n_boot, T, cols_on)
    out = np.empty(n_boot)
    for s in range(0, n_boot, chunk):
        e = min(n_boot, s + chunk)
        sub = a[ri[s:e, :, None], ci[s:e, None, :]]  # (b, R, T)
        out[s:e] = agg(sub.reshape(e - s, R * T))
    return out


def percentile_interval(replicates: np.ndarray, confidence: float = 0.95) -> tuple[float, float]:
    """The (lower, upper) percentile interval of bootstrap replicates."""
    alpha = 1.0 - confidence
    lo, hi = np.quantile(np.asarray(replicates, dtype=np.float64), [alpha / 2, 1.0 - alpha / 2])
    return float(lo), float(hi)


def bootstrap_ci(scores, stat: str = "mean", over: str = "episodes", n_boot: int = 2000, confidence: float = 0.95,
                 seed: int = 0) -> tuple[float, float]:
    """Percentile bootstrap confidence interval of ``stat`` of ``scores``.

    Args:
        scores: (n_runs, n_tasks) or (n_tasks,) finite values.
        stat: "mean", "iqm" or "median".
        over: "episodes", "seeds" or "both" (see :func:`bootstrap_distribution`).
        n_boot: number of bootstrap replicates (>= 100).
        confidence: coverage of the interval, in [0.5, 1) (default 0.95).
        seed: RNG seed (>= 0).

    Returns:
        (lower, upper).
    """
    _check_common(n_boot, confidence, seed)
    return percentile_interval(bootstrap_distribution(scores, stat, over, n_boot, seed), confidence)


def _poi_matrix(x: np.ndarray, y: np.ndarray, lower_is_better: bool) -> float:
    """Mean over tasks of the per-task Mann-Whitney statistic P(x_i better than y_j)."""
    d = x[:, None, :] - y[None, :, :]  # (Rx, Ry, T)
    if lower_is_better:
        d = -d
    per_task = ((d > 0).mean(axis=(0, 1)) + 0.5 * (d == 0).mean(axis=(0, 1)))
    return float(per_task.mean())


def probability_of_improvement(x, y, lower_is_better: bool = True) -> float:
    """P(X better than Y) in the manner of rliable.

    For each task (episode) j, the Mann-Whitney statistic ``mean_{a,b} S(x[a, j], y[b, j])`` over
    all pairs of runs, with S = 1 if X's run is better, 1/2 on a tie, 0 otherwise; then the mean
    over tasks. With one run each it is the share of episodes on which X is better (ties count 1/2).

    Args:
        x: (n_runs, n_tasks) or (n_tasks,) scores of X.
        y: the same of Y, on the *same* tasks (same column order).
        lower_is_better: direction of the score (True for the harness's ratios to the reference law).
    """
    a = _as_matrix(x, "x")
    b = _as_matrix(y, "y")
    if a.shape[1] != b.shape[1]:
        raise ValueError(f"x and y must cover the same episodes (columns), got {a.shape[1]} and {b.shape[1]}")
    return _poi_matrix(a, b, lower_is_better)


def probability_of_improvement_ci(x, y, lower_is_better: bool = True, n_boot: int = 2000, confidence: float = 0.95,
                                  seed: int = 0, chunk: int = 250) -> tuple[float, float, float]:
    """Probability of improvement with a percentile bootstrap interval.

    Each replicate resamples the episodes (the same indices for X and Y: the comparison is paired)
    and, for a policy with several runs, its runs within each episode independently (rliable's
    stratified bootstrap). Returns (point estimate, lower, upper). ``chunk``: replicates per vectorised batch
    (memory only; the result does not depend on it).
    """
    _check_common(n_boot, confidence, seed)
    _check_chunk(chunk)
    a = _as_matrix(x, "x")
    b = _as_matrix(y, "y")
    if a.shape[1] != b.shape[1]:
        raise ValueError(f"x and y must cover the same episodes (columns), got {a.shape[1]} and {b.shape[1]}")
    Rx, T = a.shape
    Ry = b.shape[0]
    rng = np.random.default_rng(int(seed))
    cols = rng.integers(0, T, size=(n_boot, T))
    rx = rng.integers(0, Rx, size=(n_boot, Rx, T)) if Rx > 1 else np.zeros((n_boot, 1, T), dtype=np.int64)
    ry = rng.integers(0, Ry, size=(n_boot, Ry, T)) if Ry > 1 else np.zeros((n_boot, 1, T), dtype=np.int64)
    reps = np.empty(n_boot)
    for s in range(0, n_boot, chunk):  # replicates in batches: the per-replicate loop spent its time in numpy calls
        e = min(n_boot, s + chunk)
        c = cols[s:e, None, :]
        reps[s:e] = _poi_batch(a[rx[s:e], c], b[ry[s:e], c], lower_is_better)
    lo, hi = percentile_interval(reps, confidence)
    return _poi_matrix(a, b, lower_is_better), lo, hi


def _poi_batch(x: np.ndarray, y: np.ndarray, lower_is_better: bool) -> np.ndarray:
    """:func:`_poi_matrix` of each replicate of a batch, x (m, Rx, T) and y (m, Ry, T), with the same arithmetic: the
    wins and ties are counted over the Rx * Ry pairs of runs (-d > 0 is d < 0, and counts are exact in any order),
    each share is its count over Rx * Ry, and each replicate's mean over the tasks is numpy's sum along the
    contiguous last axis, as of a single row."""
    m, Rx, T = x.shape
    Ry = y.shape[1]
    wins = np.zeros((m, T), dtype=np.int64)
    ties = np.zeros((m, T), dtype=np.int64)
    for i in range(Rx):
        for j in range(Ry):
            d = x[:, i, :] - y[:, j, :]
            wins += (d < 0.0) if lower_is_better else (d > 0.0)
            ties += d == 0.0
    n = Rx * Ry
    return (wins / n + 0.5 * (ties / n)).mean(axis=1)


def relative_improvement_ci(x, y, n_boot: int = 2000, confidence: float = 0.95,
                            seed: int = 0) -> tuple[float, float, float]:
    """Relative improvement ``1 - mean(x) / mean(y)`` of lower-is-better scores (> 0: X better), with a CI.

    Each percentile-bootstrap replicate resamples the episodes (the same indices for X and Y: paired)
    and the runs (rows) of each policy independently. Returns (point estimate, lower, upper).

    Args:
        x: (n_runs, n_tasks) or (n_tasks,) positive scores of X.
        y: the same of Y, on the same tasks.
    """
    _check_common(n_boot, confidence, seed)
    a = _as_matrix(x, "x")
    b = _as_matrix(y, "y")
    if a.shape[1] != b.shape[1]:
        raise ValueError(f"x and y must cover the same episodes (columns), got {a.shape[1]} and {b.shape[1]}")
    if b.mean() <= 0:
        raise ValueError("y must have a positive mean (the relative improvement divides by it)")
    rng = np.random.default_rng(int(seed))
    T = a.shape[1]
    cols = rng.integers(0, T, size=(n_boot, T))
    ra = _resample_indices(rng, n_boot, a.shape[0], a.shape[0] > 1)
    rb = _resample_indices(rng, n_boot, b.shape[0], b.shape[0] > 1)
    ma = a[ra[:, :, None], cols[:, None, :]].mean(axis=(1, 2))
    mb = b[rb[:, :, None], cols[:, None, :]].mean(axis=(1, 2))
    lo, hi = percentile_interval(1.0 - ma / mb, confidence)
    return float(1.0 - a.mean() / b.mean()), lo, hi


def _grouped_stack(groups) -> np.ndarray:
    """Groups as one (G, n_runs, n_tasks) float array (NaN = not a member); ValueError for mismatched shapes or no
    finite value."""
    mats = [np.asarray(g, dtype=np.float64) for g in groups]
    mats = [m[None, :] if m.ndim == 1 else m for m in mats]
    if not mats or any(m.ndim != 2 or m.shape != mats[0].shape or m.size == 0 for m in mats):
        raise ValueError(f"groups must be non-empty arrays of one shape, got {[m.shape for m in mats]}")
    a = np.stack(mats)
    if np.isinf(a).any() or not np.isfinite(a).any():
        raise ValueError("groups must hold finite values (NaN marks a non-member) and at least one")
    return a


def _group_means(a: np.ndarray) -> np.ndarray:
    """Mean over the last two axes of the finite entries, per group and replicate (NaN where a group has none)."""
    fin = np.isfinite(a)
    cnt = fin.sum(axis=(-2, -1))
    tot = np.where(fin, a, 0.0).sum(axis=(-2, -1))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(cnt > 0, tot / np.maximum(cnt, 1), np.nan)


def grouped_mean(groups) -> float:
    """The mean over groups of each group's mean: ``groups`` are (n_runs, n_tasks) arrays of one shape with NaN
    where an entry is not a member of the group; a group with no member is left out."""
    return float(np.nanmean(_group_means(_grouped_stack(groups))))


def grouped_mean_ci(groups, over: str = "episodes", n_boot: int = 2000, confidence: float = 0.95,
                    seed: int = 0, chunk: int = 250) -> tuple[float, float]:
    """Percentile bootstrap interval of :func:`grouped_mean`.

    Every replicate resamples the episodes (columns), the runs (rows) or both with the *same* indices for all
    groups (an episode drawn brings all its groups' entries), and takes the mean over the groups present in the
    replicate of each group's mean.

    Args:
        groups: (n_runs, n_tasks) or (n_tasks,) arrays of one shape, NaN for a non-member.
        over: "episodes", "seeds" or "both" (see :func:`bootstrap_distribution`).
        n_boot: replicates (>= 100); confidence: coverage in [0.5, 1); seed: RNG seed (>= 0).
        chunk: replicates per vectorised batch (memory only; the result does not depend on it).
    """
    if over not in OVER:
        raise ValueError(f"over must be one of {list(OVER)}, got {over!r}")
    _check_common(n_boot, confidence, seed)
    _check_chunk(chunk)
    a = _grouped_stack(groups)
    _, R, T = a.shape
    rng = np.random.default_rng(int(seed))
    ri = _resample_indices(rng, n_boot, R, over in ("seeds", "both"))
    ci = _resample_indices(rng, n_boot, T, over in ("episodes", "both"))
    reps = np.empty(n_boot)
    for s in range(0, n_boot, chunk):
        e = min(n_boot, s + chunk)
        sub = a[:, ri[s:e, :, None], ci[s:e, None, :]]  # (G, b, R, T)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # a replicate may miss a small group: left out
            reps[s:e] = np.nanmean(_group_means(sub), axis=0)
    return percentile_interval(reps[np.isfinite(reps)], confidence)


def summarize_scores(scores, n_boot: int = 2000, confidence: float = 0.95, seed: int = 0) -> dict:
    """Mean, IQM and median with bootstrap CIs over episodes, and over seeds when there are several.

    Returns a dict with keys ``n_runs``, ``n_episodes``, ``mean``, ``iqm``, ``median``, ``std`` (of all
    values), and ``{stat}_ci`` (over episodes), plus ``{stat}_ci_seeds`` (over seeds) and
    ``{stat}_ci_both`` (two-way) when n_runs > 1; each CI is (lower, upper).
    """
    a = _as_matrix(scores)
    out = {"n_runs": a.shape[0], "n_episodes": a.shape[1], "std": float(a.std(ddof=1)) if a.size > 1 else 0.0}
    for k, stat in enumerate(("mean", "iqm", "median")):
        out[stat] = aggregate(a, stat)
        out[f"{stat}_ci"] = bootstrap_ci(a, stat, "episodes", n_boot, confidence, seed + k)
        if a.shape[0] > 1:
            out[f"{stat}_ci_seeds"] = bootstrap_ci(a, stat, "seeds", n_boot, confidence, seed + 10 + k)
            out[f"{stat}_ci_both"] = bootstrap_ci(a, stat, "both", n_boot, confidence, seed + 20 + k)
    return out


__all__ = ["iqm", "aggregate", "bootstrap_distribution", "bootstrap_ci", "percentile_interval",
           "probability_of_improvement", "probability_of_improvement_ci", "relative_improvement_ci",
           "summarize_scores", "grouped_mean", "grouped_mean_ci", "STATS", "OVER"]
