"""The closed loop, compiled: one control period of B lanes, and the simulator's run of a batch.

Every period (:func:`lanes_period`): the controller of each lane (:mod:`ehss_gym.core.controller`), the plants of all
lanes integrated together over the period with the currents held (:func:`ehss_gym.core.physics.integrate_lanes`),
the divergence checks, and the metrics accumulated at the full control rate
(:func:`ehss_gym.core.metrics.accumulate`). The simulator (:func:`run_lanes`, :func:`run_batch`) and the env's step
(:func:`ehss_gym.envs.kernels.advance`) both run it, so they compute the same loop.

A lane that produces a non-finite value or leaves the state bounds (|x2| > ``omega_max``, |x3| > ``pressure_bound`` *
P_s) is stopped and reported as diverged with its time; it keeps its last finite state and no NaN is returned.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from .compensators import inverse_model_update
from .controller import CW_TODO, controller_apply, law_lanes, model_constants, sense_lanes
from .jit import jit, jit_inline, jit_noalloc
from .layout import (
    DIV_CURRENT,
    DIV_NONE,
    DIV_NONFINITE,
    DIV_OMEGA,
    DIV_PRESSURE,
    FB_VEC2,
    FBV_D_REF,
    I_DHAT,
    I_E,
    I_R,
    I_RM,
    I_S,
    I_T,
    I_TF,
    I_UAPP,
    I_UBASE,
    I_UCMD,
    I_UDOB,
    I_URES,
    I_V,
    I_W,
    I_YD,
    I_YE,
    L_DHAT,
    L_E,
    L_R,
    L_RM,
    L_S,
    L_T,
    L_TF,
    L_UAPP,
    L_UBASE,
    L_UCMD,
    L_UDOB,
    L_UMAX,
    L_UMIN,
    L_URES,
    L_V,
    L_W,
    L_X,
    L_YD,
    L_YE,
    M_DIVERGED,
    M_T_DIVERGED,
    MAX_ORDER,
    N_INFO,
    N_LOOP,
    N_PLANT,
    X_OMEGA,
    X_PL,
    X_THETA,
    Z_DELAY,
    Z_REF,
    Z_REF_RING,
    Z_SHIFT,
    Z_VINV,
)
from .metrics import accumulate
from .params import P_DF, P_PS
from .physics import N_LANE_CONST, friction_torque, integrate_lanes, lane_constants
from .settings import (
    C_ANALOG,
    C_DELAY,
    C_INV_HYSTERESIS,
    C_INV_THRESHOLD,
    C_OMEGA_MAX,
    C_ORDER,
    C_P_BOUND,
    C_REF_DELAY,
    C_SHIFT_ON,
)
from .unmodelled_kernels import valve_input

MAX_LANES = 128  # scenarios integrated in lock-step by one thread
# lane scratch (N_LWORK, N_LOOP, B): the integrator's 6 (RK4 stages, amplitudes, noise), then the controller's lane
# stages (rows CW_* of lwork[6])
N_LWORK = 7


# The loop state's rows a lane can write, in N_SPANS spans (:func:`live_span`). Most of the state belongs to add-ons
# that are off on most lanes (the sensor delay line, the valve inverse's model, the reference delay's ring, the
# reference action's filter: 87 of the N_LOOP doubles); a row no code of the lane writes keeps its reset value (0)
# and no code reads it. So the period's state copy at t_k, a diverged lane's restore from it, the look-ahead's copy
# and the divergence check cover the live spans only, with the same results (tests/test_live_rows.py fills the other
# rows with a sentinel and checks that nothing writes or reads them).
N_SPANS = 5


@jit
def live_span(ctrl, j):
    """Rows [lo, hi) of span ``j`` (< N_SPANS) of the loop state that a lane with the controller row ``ctrl`` writes
    (empty: lo == hi): the plant, filters, observers and valve play always; the sensor delay line's first N_PLANT * d
    rows for a delay of d samples (:func:`ehss_gym.core.unmodelled_kernels.delay_line`); the valve inverse's model
    with the inverse on (:func:`ehss_gym.core.compensators.inverse_model_update`); the reference ring with a
    reference delay (:func:`ehss_gym.core.compensators.law_errors`); the reference action's filter
    (:func:`ehss_gym.core.controller.controller_sense`). Each condition is its writer's own."""
    if j == 0:
        return 0, Z_DELAY
    if j == 1:
        return Z_DELAY, Z_DELAY + N_PLANT * int(ctrl[C_DELAY])
    if j == 2:
        on = ctrl[C_INV_THRESHOLD] != 0.0 or ctrl[C_INV_HYSTERESIS] != 0.0
        return Z_VINV, Z_VINV + 1 if on else Z_VINV
    if j == 3:
        return Z_REF_RING, Z_SHIFT if ctrl[C_REF_DELAY] != 0.0 else Z_REF_RING
    return Z_SHIFT, N_LOOP if ctrl[C_SHIFT_ON] != 0.0 else Z_SHIFT


@jit
def core_only(ctrl):
    """Whether the lane's live rows are the core span alone (every add-on of :func:`live_span` off), as on most
    lanes: then the copies and the check run over a fixed number of rows, which the compiler unrolls and vectorises."""
    for j in range(1, N_SPANS):
        lo, hi = live_span(ctrl, j)
        if hi > lo:
            return False
    return True


@jit_inline
def copy_live(dst, src, ctrl, first):
    """dst[i] = src[i] for the live rows i >= ``first`` of a lane's loop state (:func:`live_span`)."""
    if core_only(ctrl):
        for i in range(first, Z_DELAY):
            dst[i] = src[i]
        return
    for j in range(N_SPANS):
        lo, hi = live_span(ctrl, j)
        for i in range(max(lo, first), hi):
            dst[i] = src[i]


@jit_inline
def check_state(z, ctrl, plant_p):
    """DIV_* code of a loop state: non-finite (in a live row, :func:`live_span`; the others are neither written nor
    read), or outside the velocity/pressure bounds. A lane with add-ons has every row checked (a fixed-length loop
    that vectorises costs less than reading the lane's spans)."""
    # x - x: 0 for a finite x, NaN for inf or NaN; no exit per entry, so the loops vectorise (measured: a count over
    # the core rows, an or over all rows run fastest)
    if core_only(ctrl):
        bad = 0
        for i in range(Z_DELAY):
            bad += z[i] - z[i] != 0.0
        if bad:
            return DIV_NONFINITE
    else:
        bad_any = False
        for i in range(N_LOOP):
            bad_any |= z[i] - z[i] != 0.0
        if bad_any:
            return DIV_NONFINITE
    if abs(z[X_OMEGA]) > ctrl[C_OMEGA_MAX]:
        return DIV_OMEGA
    if abs(z[X_PL]) > ctrl[C_P_BOUND] * plant_p[P_PS]:
        return DIV_PRESSURE
    return DIV_NONE


@jit
def init_filters(z, filt, r0):
    """Reference model at its steady state for r(0) = ``r0``, estimator at rest (y(0) = 0): z[4:] in place.

    The state w of a digital filter is z - D v at the sample (layout FB_*), so w = (r0, 0, ...) - D r0.
    """
    for i in range(N_PLANT, N_LOOP):
        z[i] = 0.0
    d = filt[FB_VEC2, FBV_D_REF]
    for i in range(MAX_ORDER):
        z[Z_REF + i] = (r0 if i == 0 else 0.0) - d[i] * r0


@jit
def write_log(row, z, info):
    row[L_T] = info[I_T]
    for i in range(4):
        row[L_X + i] = z[i]
    row[L_R] = info[I_R]
    for i in range(5):
        row[L_YD + i] = info[I_YD + i]
    for i in range(4):
        row[L_YE + i] = info[I_YE + i]
        row[L_E + i] = info[I_E + i]
    row[L_S] = info[I_S]
    row[L_V] = info[I_V]
    row[L_UBASE] = info[I_UBASE]
    row[L_URES] = info[I_URES]
    row[L_UCMD] = info[I_UCMD]
    row[L_UAPP] = info[I_UAPP]
    row[L_TF] = info[I_TF]
    row[L_W] = info[I_W]
    row[L_RM] = info[I_RM]
    row[L_DHAT] = info[I_DHAT]
    row[L_UDOB] = info[I_UDOB]
    row[L_UMIN] = info[I_UAPP]  # the envelope of the sample's log interval starts here
    row[L_UMAX] = info[I_UAPP]


@jit
def widen_envelope(row, u):
    """Widen a log row's applied-current envelope (L_UMIN, L_UMAX) [mA] by one more period's current ``u``."""
    if u < row[L_UMIN]:
        row[L_UMIN] = u
    if u > row[L_UMAX]:
        row[L_UMAX] = u


@jit
def _diverge(acc, code, k, h):
    acc[M_DIVERGED] = code
    acc[M_T_DIVERGED] = (k + 1) * h


@jit_noalloc
def lanes_period(z, kv, h, substeps, plant, model, ctrl, ref, events, filt, u_res, active, info, acc, c, X, U,
                 zprev, work, lwork, pre, peek):
    """Advance every active lane by one control period, lane b from its own sample kv[b]; returns the number still
    active.

    In stages over the lanes of the block: the controller's sensors and its model at the measured states for every
    lane (:func:`ehss_gym.core.controller.sense_lanes`, reading the controller's rows of the lane constants ``c``),
    the rest of the controller's law (:func:`ehss_gym.core.controller.law_lanes`, compiled for the lanes' relative
    degree); then per lane the residual ``u_res[b]`` [mA], the current limit and the friction torque at the sample;
    then the plants of all lanes integrated together; then the divergence checks and the metrics. The lanes need not
    be at the same sample (lanes reset at different times are out of phase): each computes its own, as a block of one
    would. ``lwork`` is scratch (N_LWORK, N_LOOP, B). A lane that diverges is marked inactive, keeps its last finite
    state, and gets its DIV_* code and time in ``acc``. ``zprev`` receives the
    state at t_k (what the logged sample shows).

    A lane with ``pre[b]`` set has already been sensed at this k from this state
    (:func:`ehss_gym.core.controller.controller_sense` and the filter advance, as the
    env's look-ahead does): ``peek[b, :N_INFO]`` holds that info and
    ``peek[b, N_INFO:]`` the loop state after the filter advance. The controller
    then only applies the residual (same arithmetic, bit for bit), and
    ``pre[b]`` is cleared. The simulator passes no such lanes.
    """
    B = z.shape[0]
    n_active = 0
    analog = False
    for b in range(B):
        if active[b] and ctrl[b, C_ANALOG] != 0.0:
            analog = True
    nx = N_LOOP if analog else N_PLANT  # rows integrated: the plant, and with analog lanes the filters too
    ynoise = lwork[5, 1]
    t0 = lwork[5, 3]  # each lane's time at its sample [s]
    cw = lwork[6]  # the controller's lane stages (rows CW_*)
    # stage: the state at t_k of every active lane (before the controller's sensors move the delay line in z), and
    # which lanes the controller senses afresh (active, not pre-sensed by the env's look-ahead)
    n_todo = 0
    for b in range(B):
        if active[b]:
            copy_live(zprev[b], z[b], ctrl[b], 0)
        sense = active[b] and not pre[b]
        cw[CW_TODO, b] = 1.0 if sense else 0.0
        n_todo += sense
    # stages 1-2 of the controller, each over the lanes: the sensors, the model at the measured states (vectorised);
    # then stages 3 on over the lanes, compiled for their relative degree
    if n_todo > 0:
        sense_lanes(z, kv, ctrl, c, cw)
        law_lanes(z, kv, h, ctrl, ref, filt, info, work, cw)
    for b in range(B):
        if not active[b]:
            U[b] = 0.0
            continue
        if pre[b]:
            pre[b] = False
            for i in range(N_INFO):
                info[b, i] = peek[b, i]
            copy_live(z[b], peek[b, N_INFO:], ctrl[b], N_PLANT)
            u_base = peek[b, I_UBASE]
        else:  # the law's current, from law_lanes
            u_base = info[b, I_UBASE]
        u = controller_apply(z[b], info[b], ctrl[b], u_base, u_res[b])
        t0[b] = kv[b] * h
        info[b, I_TF] = friction_torque(t0[b], zprev[b, X_OMEGA], events[b], plant[b, P_DF])  # the plant's, at t_k
        if not (math.isfinite(u) and math.isfinite(info[b, I_V]) and math.isfinite(info[b, I_S])):
            _diverge(acc[b], DIV_CURRENT if not math.isfinite(u) else DIV_NONFINITE, kv[b], h)
            active[b] = False
            copy_live(z[b], zprev[b], ctrl[b], 0)
            U[b] = 0.0
            continue
        U[b] = valve_input(z[b], u, ctrl[b])  # the valve's threshold and hysteresis (off: u)
        inverse_model_update(z[b], u, ctrl[b])  # the valve inverse's model of it (off: nothing)
        for i in range(nx):
            X[i, b] = z[b, i]
        # the sensor noise on the output at this sample, held over the period for an analog estimator
        ynoise[b] = info[b, I_YE] - z[b, X_THETA if ctrl[b, C_ORDER] == 4 else X_OMEGA]
        n_active += 1
    if n_active == 0:
        return 0
    integrate_lanes(X, U, t0, h, substeps, c, events, lwork, analog, ctrl, ref, filt, ynoise)
    for b in range(B):
        if not active[b]:
            continue
        for i in range(nx):
            z[b, i] = X[i, b]
        code = check_state(z[b], ctrl[b], plant[b])
        if code != DIV_NONE:
            _diverge(acc[b], code, kv[b], h)
            active[b] = False
            copy_live(z[b], zprev[b], ctrl[b], 0)
            for i in range(nx):
                X[i, b] = z[b, i]
            n_active -= 1
            continue
        accumulate(acc[b], info[b], h, kv[b], events[b])
    return n_active


@jit
def run_lanes(z, h, substeps, n_steps, log_every, plant, model, ctrl, ref, events, filt, log, acc, n_log):
    """Simulate B scenarios in lock-step from k = 0 with no residual, logging every ``log_every`` periods."""
    B = z.shape[0]
    c = np.zeros((N_LANE_CONST, B))
    lane_constants(plant, c)
    model_constants(model, ctrl, c)
    X = np.zeros((N_LOOP, B))
    U = np.zeros(B)
    u_res = np.zeros(B)
    active = np.ones(B, dtype=np.bool_)
    info = np.zeros((B, N_INFO))
    work = np.zeros((8, 4))
    lwork = np.zeros((N_LWORK, N_LOOP, B))
    zprev = np.zeros_like(z)
    pre = np.zeros(B, dtype=np.bool_)  # no lane is pre-sensed in a plain simulation
    peek = np.zeros((B, N_INFO + N_LOOP))
    kv = np.zeros(B, dtype=np.int64)  # the lanes' sample index: all in phase here
    for b in range(B):
        acc[b, M_T_DIVERGED] = -1.0
        n_log[b] = 0
    for k in range(n_steps):
        kv[:] = k
        if lanes_period(z, kv, h, substeps, plant, model, ctrl, ref, events, filt, u_res, active, info, acc, c, X, U,
                        zprev, work, lwork, pre, peek) == 0:
            break
        log_now = k % log_every == 0
        for b in range(B):
            if not active[b]:
                continue
            if log_now:
                write_log(log[b, n_log[b]], zprev[b], info[b])
                n_log[b] += 1
            else:  # between samples: the current's envelope over the log interval (no aliasing of the switching)
                widen_envelope(log[b, n_log[b] - 1], info[b, I_UAPP])


@nb.njit(parallel=True, cache=True, error_model="numpy")
def run_batch(z, h, substeps, n_steps, log_every, plant, model, ctrl, ref, events, filt, log, acc, n_log, chunk):
    """Simulate a batch: chunks of ``chunk`` scenarios in parallel, lanes within a chunk."""
    B = z.shape[0]
    n_chunks = (B + chunk - 1) // chunk
    for i in nb.prange(n_chunks):
        s = i * chunk
        e = min(B, s + chunk)
        run_lanes(z[s:e], h, substeps, n_steps, log_every, plant[s:e], model[s:e], ctrl[s:e], ref[s:e],
                  events[s:e], filt[s:e], log[s:e], acc[s:e], n_log[s:e])


__all__ = ["lanes_period", "run_lanes", "run_batch", "check_state", "init_filters", "write_log", "widen_envelope",
           "live_span", "core_only", "copy_live", "MAX_LANES", "N_LWORK", "N_SPANS"]
