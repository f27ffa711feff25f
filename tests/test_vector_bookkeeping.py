"""The vector env's compiled bookkeeping around its step (:func:`ehss_gym.envs.kernels.vector_actions`,
:func:`~ehss_gym.envs.kernels.vector_ends`) against the same rules written as whole-array numpy expressions, on random
sub-env states."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from ehss_gym.core.layout import M_LOST, N_METRICS
from ehss_gym.envs.kernels import vector_actions, vector_ends


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), N=st.integers(1, 40), k=st.integers(1, 4), pad=st.integers(0, 3),
       nan=st.booleans())
def test_actions_are_checked_clipped_and_launched_as_numpy_does(seed, N, k, pad, nan):
    rng = np.random.default_rng(seed)
    a = rng.choice([-np.inf, -3.0, -1.0, -0.5, -0.0, 0.0, 0.7, 1.0, 1.0 + 1e-16, 2.0, np.inf], size=(N, k))
    a += rng.uniform(-0.1, 0.1, (N, k)) * (rng.random((N, k)) < 0.5)
    if nan:
        a[rng.integers(N), rng.integers(k)] = np.nan
    autoreset, ended = rng.random(N) < 0.2, rng.random(N) < 0.2
    out, clipped, stepped = np.full((N, k), 7.0), np.zeros(N, np.bool_), np.zeros(N, np.bool_)
    n_clipped = rng.integers(0, 5, N)
    run = rng.random(N + pad) < 0.5
    n_before, run_before = n_clipped.copy(), run.copy()
    n_reset, n_step = vector_actions(a, autoreset, ended, out, clipped, stepped, n_clipped, run)
    if np.isnan(a).any():  # refused, nothing written
        assert (n_reset, n_step) == (0, -1)
        assert (out == 7.0).all() and not clipped.any() and not stepped.any()
        assert np.array_equal(n_clipped, n_before) and np.array_equal(run, run_before)
        return
    want_stepped = ~(autoreset | ended)
    want_clipped = ((a > 1.0) | (a < -1.0)).any(axis=1) & want_stepped
    assert np.array_equal(out, np.clip(a, -1.0, 1.0))
    assert np.array_equal(np.signbit(out), np.signbit(np.clip(a, -1.0, 1.0)))
    assert np.array_equal(stepped, want_stepped)
    assert np.array_equal(clipped, want_clipped)
    assert (n_reset, n_step) == (int(autoreset.sum()), int(want_stepped.sum()))
    # the launch: clipped actions counted, the lanes that do not step stopped, the padding lanes untouched
    want_run = run_before.copy()
    want_run[:N][~want_stepped] = False
    assert np.array_equal(n_clipped, n_before + want_clipped) and np.array_equal(run, want_run)


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), N=st.integers(1, 40), pad=st.integers(0, 3), n=st.integers(1, 5),
       stop_lost=st.booleans())
def test_the_ends_flags_and_info_copies_follow_the_numpy_rules(seed, N, pad, n, stop_lost):
    rng = np.random.default_rng(seed)
    B = N + pad
    run = rng.random(B) < 0.7
    acc = rng.uniform(0, 1, (B, N_METRICS))
    acc[:, M_LOST] = rng.random(B) < 0.3
    T = rng.integers(1, 8, B)
    steps = rng.integers(0, 8, N)
    stepped, autoreset = rng.random(N) < 0.8, rng.random(N) < 0.2
    info_ok, stats, rew = rng.normal(size=(B, 37)), rng.normal(size=(B, 15)), rng.normal(size=B)
    # the rules as the vector env wrote them with numpy
    r, s = run[:N].copy(), steps.copy()
    diverged = stepped & ~r
    lost = acc[:N, M_LOST] > 0.0
    if stop_lost:
        r &= ~(stepped & lost)
    terminated = stepped & ~r
    s[stepped] += n
    truncated = stepped & r & (s >= T[:N])
    r[autoreset] = True
    flags = np.empty((5, N), np.bool_)
    info_t, stats_t, rewards = np.empty((37, N)), np.empty((15, N)), np.full(N, np.nan)
    run_before_pad = run[N:].copy()
    n_end = vector_ends(run, acc, T, steps, stepped, autoreset, n, stop_lost, info_ok, stats, rew, flags, info_t,
                        stats_t, rewards)
    assert np.array_equal(rewards, np.where(stepped, rew[:N], 0.0))
    assert np.array_equal(flags, np.stack([diverged, lost, terminated, truncated, terminated | truncated]))
    assert n_end == int((terminated | truncated).sum())
    assert np.array_equal(run[:N], r) and np.array_equal(run[N:], run_before_pad) and np.array_equal(steps, s)
    assert np.array_equal(info_t, info_ok[:N].T) and np.array_equal(stats_t, stats[:N].T)
