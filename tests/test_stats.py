"""Statistics of the evaluation harness against known answers."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats as sps

from ehss_gym.evaluation import stats


def test_iqm_known_values():
    # 8 values: floor(8/4) = 2 cut from each end -> mean(3, 4, 5, 6)
    assert stats.iqm([8, 1, 7, 2, 6, 3, 5, 4]) == pytest.approx(4.5)
    # an outlier does not move the IQM, it does move the mean
    x = np.array([1.0, 2, 3, 4, 5, 6, 7, 1e9])
    assert stats.iqm(x) == pytest.approx(4.5)
    assert stats.aggregate(x, "mean") > 1e8


@pytest.mark.parametrize("n", [4, 5, 7, 10, 33, 100])
def test_iqm_equals_scipy_trim_mean(n):
    rng = np.random.default_rng(n)
    x = rng.lognormal(size=n)
    assert stats.iqm(x) == pytest.approx(sps.trim_mean(x, 0.25), rel=1e-12)
    # a matrix is flattened (rliable pools runs and tasks)
    m = rng.normal(size=(3, n))
    assert stats.iqm(m) == pytest.approx(sps.trim_mean(m.ravel(), 0.25), rel=1e-12)


def test_aggregate_and_bad_input():
    assert stats.aggregate([1, 2, 3, 10], "median") == pytest.approx(2.5)
    with pytest.raises(ValueError, match="stat must be one of"):
        stats.aggregate([1, 2], "max")
    with pytest.raises(ValueError, match="finite"):
        stats.aggregate([1, float("nan")])
    with pytest.raises(ValueError, match="shape"):
        stats.aggregate(np.zeros((2, 2, 2)))
    with pytest.raises(ValueError, match="over must be one of"):
        stats.bootstrap_ci([1, 2, 3], over="tasks")
    with pytest.raises(ValueError, match="n_boot"):
        stats.bootstrap_ci([1, 2, 3], n_boot=10)
    with pytest.raises(ValueError, match="confidence"):
        stats.bootstrap_ci([1, 2, 3], confidence=1.5)
    with pytest.raises(ValueError, match="seed"):
        stats.bootstrap_ci([1, 2, 3], seed=-1)
    with pytest.raises(ValueError, match="same episodes"):
        stats.probability_of_improvement([1, 2], [1, 2, 3])
    for bad in (0, -1, 2.5, True):  # replicates per batch: a clear error, not range()'s
        with pytest.raises(ValueError, match="chunk must be an integer >= 1"):
            stats.bootstrap_distribution([1, 2, 3], chunk=bad)
        with pytest.raises(ValueError, match="chunk must be an integer >= 1"):
            stats.probability_of_improvement_ci([1, 2, 3], [2, 3, 4], chunk=bad)
        with pytest.raises(ValueError, match="chunk must be an integer >= 1"):
            stats.grouped_mean_ci([np.array([1.0, 2.0])], chunk=bad)


def test_bootstrap_ci_constant_is_degenerate_and_seeded():
    assert stats.bootstrap_ci(np.full(20, 3.0)) == (3.0, 3.0)
    rng = np.random.default_rng(0)
    x = rng.normal(size=50)
    a = stats.bootstrap_ci(x, "iqm", seed=7)
    b = stats.bootstrap_ci(x, "iqm", seed=7)
    c = stats.bootstrap_ci(x, "iqm", seed=8)
    assert a == b
    assert a != c


def test_bootstrap_ci_mean_matches_normal_theory():
    # for a large sample, the percentile interval of the mean ~ mean +- 1.96 s / sqrt(n)
    rng = np.random.default_rng(1)
    x = rng.normal(10.0, 2.0, size=400)
    lo, hi = stats.bootstrap_ci(x, "mean", n_boot=4000, seed=3)
    half = 1.96 * x.std(ddof=1) / math.sqrt(x.size)
    assert (hi - lo) / 2 == pytest.approx(half, rel=0.1)
    assert (lo + hi) / 2 == pytest.approx(x.mean(), abs=0.1 * half)


def test_bootstrap_ci_coverage():
    # the 95 % interval of the mean should contain the true mean in about 95 % of repeated experiments
    rng = np.random.default_rng(2)
    hits = 0
    reps = 200
    for i in range(reps):
        x = rng.normal(1.0, 1.0, size=40)
        lo, hi = stats.bootstrap_ci(x, "mean", n_boot=1000, seed=i)
        hits += lo <= 1.0 <= hi
    assert 0.89 <= hits / reps <= 0.99


def test_bootstrap_over_seeds_and_both():
    # rows differ by a constant seed effect: resampling episodes only sees no seed spread
    base = np.linspace(0.0, 1.0, 30)
    m = np.stack([base + off for off in (0.0, 1.0, 2.0, 3.0, 4.0)])  # 5 seeds
    lo_e, hi_e = stats.bootstrap_ci(m, over="episodes", seed=0)
    lo_s, hi_s = stats.bootstrap_ci(m, over="seeds", seed=0)
    lo_b, hi_b = stats.bootstrap_ci(m, over="both", seed=0)
    assert hi_s - lo_s > 3 * (hi_e - lo_e)  # seeds dominate the uncertainty here
    assert hi_b - lo_b >= hi_s - lo_s - 1e-9 - 0.2 * (hi_s - lo_s)
    for lo, hi in ((lo_e, hi_e), (lo_s, hi_s), (lo_b, hi_b)):
        assert lo <= m.mean() <= hi
    # a single run resampled over seeds is degenerate
    assert stats.bootstrap_ci(base, over="seeds") == pytest.approx((base.mean(), base.mean()))


def test_bootstrap_does_not_depend_on_chunking():
    x = np.random.default_rng(4).normal(size=(3, 25))
    a = stats.bootstrap_distribution(x, "iqm", "both", n_boot=700, seed=5, chunk=64)
    b = stats.bootstrap_distribution(x, "iqm", "both", n_boot=700, seed=5, chunk=700)
    np.testing.assert_array_equal(a, b)


def test_probability_of_improvement_known_values():
    x = np.array([1.0, 1.0, 1.0, 1.0])
    y = np.array([2.0, 2.0, 0.5, 1.0])
    # lower is better: x wins on 2 episodes, loses on 1, ties on 1 -> (2 + 0.5) / 4
    assert stats.probability_of_improvement(x, y) == pytest.approx(0.625)
    assert stats.probability_of_improvement(y, x) == pytest.approx(0.375)
    assert stats.probability_of_improvement(x, y, lower_is_better=False) == pytest.approx(0.375)
    assert stats.probability_of_improvement(x, x) == 0.5
    assert stats.probability_of_improvement(x, x + 1) == 1.0


def test_probability_of_improvement_is_mann_whitney_per_task():
    # one task with several runs: P(X > Y) = U / (n_x n_y), scipy's Mann-Whitney U of x
    rng = np.random.default_rng(5)
    xr = rng.normal(0.3, 1.0, size=7)
    yr = rng.normal(0.0, 1.0, size=9)
    U = sps.mannwhitneyu(xr, yr).statistic
    p = stats.probability_of_improvement(xr[:, None], yr[:, None], lower_is_better=False)
    assert p == pytest.approx(U / (7 * 9))
    # several tasks: the mean of the per-task statistics
    X = rng.normal(size=(4, 3))
    Y = rng.normal(size=(5, 3))
    per = [sps.mannwhitneyu(X[:, j], Y[:, j]).statistic / 20 for j in range(3)]
    assert stats.probability_of_improvement(X, Y, lower_is_better=False) == pytest.approx(np.mean(per))


def test_probability_of_improvement_ci():
    rng = np.random.default_rng(6)
    y = rng.lognormal(size=60)
    better = 0.7 * y  # better on every episode
    p, lo, hi = stats.probability_of_improvement_ci(better, y, seed=1)
    assert (p, lo, hi) == (1.0, 1.0, 1.0)
    noisy = y * rng.lognormal(0.0, 0.5, size=60)  # no systematic difference
    p, lo, hi = stats.probability_of_improvement_ci(noisy, y, seed=1)
    assert lo < 0.5 < hi
    assert lo <= p <= hi
    # with several seeds the interval is at least as wide (run resampling adds uncertainty)
    runs = np.stack([y * rng.lognormal(0.0, 0.5, size=60) for _ in range(5)])
    p2, lo2, hi2 = stats.probability_of_improvement_ci(runs, y, seed=1)
    assert lo2 <= p2 <= hi2


def test_summarize_scores_keys():
    s1 = stats.summarize_scores(np.arange(20.0))
    assert s1["n_runs"] == 1 and s1["n_episodes"] == 20
    assert s1["mean"] == pytest.approx(9.5)
    assert s1["iqm"] == pytest.approx(sps.trim_mean(np.arange(20.0), 0.25))
    assert "mean_ci_seeds" not in s1
    lo, hi = s1["iqm_ci"]
    assert lo < s1["iqm"] < hi
    s2 = stats.summarize_scores(np.arange(40.0).reshape(2, 20))
    assert "mean_ci_seeds" in s2 and "iqm_ci_both" in s2


def test_relative_improvement_ci():
    rng = np.random.default_rng(7)
    y = rng.lognormal(size=50)
    p, lo, hi = stats.relative_improvement_ci(0.8 * y, y, seed=2)
    assert p == pytest.approx(0.2)
    assert lo == pytest.approx(0.2) and hi == pytest.approx(0.2)  # an exact 20 % on every episode
    x = y * rng.lognormal(0.0, 0.3, size=50)
    p, lo, hi = stats.relative_improvement_ci(x, y, seed=2)
    assert p == pytest.approx(1 - x.mean() / y.mean())
    assert lo < p < hi
    # several runs: the seed spread widens the interval
    runs = np.stack([y * f for f in (0.6, 0.8, 1.0, 1.2, 1.4)])
    p1, lo1, hi1 = stats.relative_improvement_ci(runs, y, seed=2)
    assert p1 == pytest.approx(0.0, abs=1e-12)
    assert hi1 - lo1 > 0.2
    with pytest.raises(ValueError, match="positive mean"):
        stats.relative_improvement_ci([1.0, 2.0], [0.0, 0.0])


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), rx=st.integers(1, 6), ry=st.integers(1, 6), T=st.integers(1, 140),
       lower=st.booleans(), chunk=st.sampled_from([1, 37, 250]))
def test_the_batched_replicates_are_the_per_replicate_statistic_bit_for_bit(seed, rx, ry, T, lower, chunk):
    """probability_of_improvement_ci's replicates in batches against the statistic taken on each replicate alone
    (the Mann-Whitney shares as means over both runs' axes), on scores with many ties, either direction."""
    rng = np.random.default_rng(seed)
    x = rng.choice([0.5, 1.0, 1.5], size=(rx, T)) + rng.normal(size=(rx, T)) * (rng.random() < 0.5)
    y = rng.choice([0.5, 1.0, 1.5], size=(ry, T)) + rng.normal(size=(ry, T)) * (rng.random() < 0.5)
    n_boot = 120
    draw = np.random.default_rng(seed)  # the function's draws, in its order
    cols = draw.integers(0, T, size=(n_boot, T))
    ri = draw.integers(0, rx, size=(n_boot, rx, T)) if rx > 1 else np.zeros((n_boot, 1, T), dtype=np.int64)
    rj = draw.integers(0, ry, size=(n_boot, ry, T)) if ry > 1 else np.zeros((n_boot, 1, T), dtype=np.int64)
    reps = np.array([stats._poi_matrix(x[ri[i], cols[i][None, :]], y[rj[i], cols[i][None, :]], lower)
                     for i in range(n_boot)])
    assert np.array_equal(stats._poi_batch(x[ri, cols[:, None, :]], y[rj, cols[:, None, :]], lower), reps)
    want = stats.percentile_interval(reps, 0.9)
    point, lo, hi = stats.probability_of_improvement_ci(x, y, lower, n_boot=n_boot, confidence=0.9, seed=seed,
                                                        chunk=chunk)
    assert (lo, hi) == want and point == stats.probability_of_improvement(x, y, lower)
