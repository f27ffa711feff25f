r"""The EHSS plant, Eq. (1), and its Lie derivatives, as pure compiled functions.

Model (docs/MODEL.md, "The plant"; friction T_f from the event list, Eq. 25)::

    x1' = x2
    x2' = (d_m x3 - B x2 - T_f) / J
    x3' = (4 beta / V_m) (Q(x3, x4) - d_m x2 - c_sm x3)
    x4' = (K u - x4) / tau

    Q   = c_d x4 R(P_s - sigm(x4) x3)            orifice flow [m^3/s]
    R(p) = p / sqrt(rho sqrt(p^2 + p_t^2))       ~ sign(p) sqrt(|p| / rho)
    sigm(x) = x / sqrt(x^2 + delta)              smooth sign, Eq. (2)
    T_f = sum_active(A_i) sigm(x2)               Coulomb friction events
    |x3| <= P_s                                  ideal cross-port relief valves

Lie derivatives. With the friction left out, f(x) is the drift and
g = (0, 0, 0, K/tau) the input vector. For the velocity output y = x2::

    h0 = x2,  h1 = f2 = (d_m x3 - B x2)/J,  h2 = (d_m f3 - B f2)/J
    y''' = F + G u,
    F = (d_m/J) C (Q_3 f3 + Q_4 f4 - d_m f2 - c_sm f3) - (B/J) h2
    G = (d_m/J) C Q_4 K / tau

with C = 4 beta / V_m, Q_3 = dQ/dx3, Q_4 = dQ/dx4. The position output y = x1
has one more integrator: h = (x1, x2, f2, h2) and y'''' = F + G u with the same
F and G. These are checked against finite differences and a symbolic
derivation in ``tests/test_physics.py``.

The loop's one integrator is here too: :func:`integrate_lanes` advances B loops over a control period by classic
RK4, the plants and, for the "analog" estimator, the continuous reference model and state-variable filter with them
(:func:`analog_filter_rhs`).
"""

from __future__ import annotations

import math

import numpy as np

from .jit import jit, jit_inline, jit_noalloc
from .layout import (
    EV_AMP,
    EV_END,
    EV_START,
    FB_VEC,
    FBV_C_EST,
    FBV_C_REF,
    MAX_ORDER,
    N_FB,
    N_PARAM,
    N_PLANT,
    N_REF,
    X_AV,
    X_OMEGA,
    X_PL,
    X_THETA,
    Z_EST,
    Z_REF,
)
from .params import P_B, P_BETA, P_CD, P_CSM, P_DF, P_DM, P_DPT, P_DV, P_J, P_K, P_PS, P_RHO, P_TAU, P_VM
from .references import reference_value
from .settings import C_ANALOG, C_ORDER, N_CTRL


@jit
def sigm(x, delta):
    """Smooth sign x / sqrt(x^2 + delta), Eq. (2). Odd, in (-1, 1)."""
    return x / math.sqrt(x * x + delta)


@jit
def dsigm(x, delta):
    """d sigm / dx = delta / (x^2 + delta)^(3/2)."""
    q = x * x + delta
    return delta / (q * math.sqrt(q))


@jit
def orifice_root(dp, rho, dp_t):
    """R(dp) = dp / sqrt(rho sqrt(dp^2 + dp_t^2)) [m/s]; ~sign(dp) sqrt(|dp|/rho)."""
    return dp / math.sqrt(rho * math.sqrt(dp * dp + dp_t * dp_t))


@jit
def orifice_root_prime(dp, rho, dp_t):
    """dR/d(dp) = (dp^2/2 + dp_t^2) / (sqrt(rho) (dp^2 + dp_t^2)^(5/4))."""
    q = dp * dp + dp_t * dp_t
    return (0.5 * dp * dp + dp_t * dp_t) / (math.sqrt(rho) * q * math.sqrt(math.sqrt(q)))


@jit
def relief(x3, ps):
    """Ideal cross-port relief valves at +-P_s: project the load pressure back into [-P_s, P_s].

    Not in the paper. Without it the motor, pumping against a nearly closed
    valve while the load reverses, drives |x3| above P_s (seen: 1.28 P_s under
    +-10 mA switching). A NaN passes through unchanged, to be caught as divergence.
    """
    if x3 > ps:
        return ps
    if x3 < -ps:
        return -ps
    return x3


@jit
def active_amplitude(t, events):
    """Sum of the amplitudes [N*m] of the friction events active at time t [s]."""
    amp = 0.0
    for i in range(events.shape[0]):
        if events[i, EV_START] <= t < events[i, EV_END]:
            amp += events[i, EV_AMP]
    return amp


@jit
def friction_torque(t, omega, events, delta_friction):
    """Coulomb friction torque [N*m] of all events active at time t.

    An event (A, t_start, t_end) is active for t_start <= t < t_end.
    """
    return active_amplitude(t, events) * (omega / math.sqrt(omega * omega + delta_friction))


@jit
def plant_rhs(x, u, tf, p, dx):
    """Write x' of Eq. (1) into ``dx`` for current u [mA] and friction tf [N*m] (one state; the loop integrates
    :func:`lane_rhs`, the same expressions over lanes)."""
    x2 = x[X_OMEGA]
    x3 = x[X_PL]
    x4 = x[X_AV]
    sv = x4 / math.sqrt(x4 * x4 + p[P_DV])
    dp = p[P_PS] - sv * x3
    q = p[P_CD] * x4 * dp / math.sqrt(p[P_RHO] * math.sqrt(dp * dp + p[P_DPT] * p[P_DPT]))
    dx[X_THETA] = x2
    dx[X_OMEGA] = p[P_DM] / p[P_J] * x3 - p[P_B] / p[P_J] * x2 - 1.0 / p[P_J] * tf
    dx[X_PL] = 4.0 * p[P_BETA] / p[P_VM] * (q - p[P_DM] * x2 - p[P_CSM] * x3)
    dx[X_AV] = p[P_K] / p[P_TAU] * u - 1.0 / p[P_TAU] * x4


# Lane constants: per-scenario coefficients laid out (N_LANE_CONST, lanes) so the
# inner loop over lanes reads contiguous memory and vectorises.
LC_DMJ, LC_BJ, LC_IJ, LC_C, LC_CD, LC_PS, LC_RHO, LC_DPT2, LC_KT, LC_IT, LC_DV, LC_DF, LC_CSM, LC_DM = range(14)
# The controller's rows, filled by :func:`ehss_gym.core.controller.model_constants`: its model of the plant (N_PARAM
# rows in P_* order) and the bound of the model's pressure domain [Pa], read by its lane stages.
LC_MODEL = 14
LC_PMAX = LC_MODEL + N_PARAM
N_LANE_CONST = LC_PMAX + 1


@jit
def lane_constants(P, out):
    """Fill the plant's rows of ``out`` (N_LANE_CONST, B) from plant parameter rows ``P`` (B, n_params)."""
    for b in range(P.shape[0]):
        p = P[b]
        out[LC_DMJ, b] = p[P_DM] / p[P_J]
        out[LC_BJ, b] = p[P_B] / p[P_J]
        out[LC_IJ, b] = 1.0 / p[P_J]
        out[LC_C, b] = 4.0 * p[P_BETA] / p[P_VM]
        out[LC_CD, b] = p[P_CD]
        out[LC_PS, b] = p[P_PS]
        out[LC_RHO, b] = p[P_RHO]
        out[LC_DPT2, b] = p[P_DPT] * p[P_DPT]
        out[LC_KT, b] = p[P_K] / p[P_TAU]
        out[LC_IT, b] = 1.0 / p[P_TAU]
        out[LC_DV, b] = p[P_DV]
        out[LC_DF, b] = p[P_DF]
        out[LC_CSM, b] = p[P_CSM]
        out[LC_DM, b] = p[P_DM]


@jit
def lane_rhs(X, A, U, c, D, B):
    """D[:, b] = x' for every lane b; X, D are (4, B); A = friction amplitudes (B,)."""
    for b in range(B):
        x2 = X[1, b]
        x3 = X[2, b]
        x4 = X[3, b]
        sv = x4 / math.sqrt(x4 * x4 + c[LC_DV, b])
        dp = c[LC_PS, b] - sv * x3
        q = c[LC_CD, b] * x4 * dp / math.sqrt(c[LC_RHO, b] * math.sqrt(dp * dp + c[LC_DPT2, b]))
        tf = A[b] * (x2 / math.sqrt(x2 * x2 + c[LC_DF, b]))
        D[0, b] = x2
        D[1, b] = c[LC_DMJ, b] * x3 - c[LC_BJ, b] * x2 - c[LC_IJ, b] * tf
        D[2, b] = c[LC_C, b] * (q - c[LC_DM, b] * x2 - c[LC_CSM, b] * x3)
        D[3, b] = c[LC_KT, b] * U[b] - c[LC_IT, b] * x4


@jit_inline
def lie_terms(x2, x3, x4, p, o):
    """The model's f2 = x2', h2 = x2'' along the friction-free drift and (F, G) at the state (x2, x3, x4), for
    :func:`lie_derivatives` (one state) and the controller's lane stage (every lane of a block, vectorised).

    ``p[o + P_*]`` are the model's parameters: o = 0 for a parameter row, LC_MODEL for a lane's column of the lane
    constants.

    Returns:
        (f2, h2, F, G): [rad/s^2], [rad/s^3], F [output unit / s^m], G [output unit / s^m per mA].
    """
    J = p[o + P_J]
    B = p[o + P_B]
    dm = p[o + P_DM]
    C = 4.0 * p[o + P_BETA] / p[o + P_VM]
    sv = sigm(x4, p[o + P_DV])
    dp = p[o + P_PS] - sv * x3
    R = orifice_root(dp, p[o + P_RHO], p[o + P_DPT])
    Rp = orifice_root_prime(dp, p[o + P_RHO], p[o + P_DPT])
    Q = p[o + P_CD] * x4 * R
    Q3 = -p[o + P_CD] * x4 * Rp * sv
    Q4 = p[o + P_CD] * (R - x4 * Rp * dsigm(x4, p[o + P_DV]) * x3)
    f2 = (dm * x3 - B * x2) / J
    f3 = C * (Q - dm * x2 - p[o + P_CSM] * x3)
    f4 = -x4 / p[o + P_TAU]
    h2 = (dm * f3 - B * f2) / J
    F = dm / J * C * (Q3 * f3 + Q4 * f4 - dm * f2 - p[o + P_CSM] * f3) - B / J * h2
    G = dm / J * C * Q4 * p[o + P_K] / p[o + P_TAU]
    return f2, h2, F, G


@jit
def lie_derivatives(x, p, order, h):
    """Output derivatives along the friction-free model, and the input gain.

    Args:
        x: plant state (4,).
        p: model parameters (PlantParams.as_array()).
        order: relative degree m: 3 (velocity output x2) or 4 (position x1).
        h: output array (>= m,), receives y, y', ..., y^(m-1) as functions of x.

    Returns:
        (F, G): y^(m) = F + G u, with F in [output unit / s^m] and
        G in [output unit / s^m per mA].
    """
    x2 = x[X_OMEGA]
    f2, h2, F, G = lie_terms(x2, x[X_PL], x[X_AV], p, 0)
    if order == 3:
        h[0] = x2
        h[1] = f2
        h[2] = h2
    else:
        h[0] = x[X_THETA]
        h[1] = x2
        h[2] = f2
        h[3] = h2
    return F, G


# --- The loop's integrator: RK4 over a control period, the plants and the analog filters ------------------


@jit
def analog_filter_rhs(X, ts, ctrl, ref, filt, ynoise, D, B):
    """D[4:, b] = the continuous reference model's and estimator's derivatives for the "analog" lanes.

    The reference model of lane b is driven by r(ts[b]) (``ts``: each lane's time [s]), the estimator by the plant
    output in X plus the sensor noise of the last sample (held: a sampled sensor). Other lanes get zeros (their filters
    are digital).
    """
    for b in range(B):
        for i in range(N_PLANT, D.shape[0]):
            D[i, b] = 0.0
        if ctrl[b, C_ANALOG] == 0.0:
            continue
        m = int(ctrl[b, C_ORDER])
        cr = filt[b, FB_VEC, FBV_C_REF]
        acc = cr[0] * reference_value(ts[b], ref[b])
        for i in range(m):
            acc -= cr[i] * X[Z_REF + i, b]
        for i in range(m - 1):
            D[Z_REF + i, b] = X[Z_REF + i + 1, b]
        D[Z_REF + m - 1, b] = acc
        ce = filt[b, FB_VEC, FBV_C_EST]
        me = m - 1
        y = (X[X_THETA, b] if m == 4 else X[X_OMEGA, b]) + ynoise[b]
        acc = ce[0] * y
        for i in range(me):
            acc -= ce[i] * X[Z_EST + i, b]
        for i in range(me - 1):
            D[Z_EST + i, b] = X[Z_EST + i + 1, b]
        D[Z_EST + me - 1, b] = acc


@jit_noalloc
def integrate_lanes(X, U, t0, h, substeps, c, events, work, analog, ctrl, ref, filt, ynoise):
    """Advance B loops, lane b over [t0[b], t0[b] + h], with their currents held (ZOH): classic RK4, ``substeps``
    equal steps. Each lane has its own start time (lanes reset at different times are out of phase).

    The plant rows X[:4] of every lane are integrated (:func:`lane_rhs`); with ``analog`` also the filter rows X[4:]
    of the lanes whose estimator is analog: the reference model (input r(t)) and the estimator (input y(t) + the
    held noise) in the same RK4 stages (:func:`analog_filter_rhs`), so they see the plant's intra-period motion as a
    continuous filter would. Friction events switch on the substep grid: the amplitude is taken at each substep's
    midpoint and held over it, so an edge on the grid is exact and one between grid points is resolved to within a
    substep (evaluating it per RK4 stage would let the step just before an edge see the new value at its end point).

    Args:
        X: loop states (N_LOOP, B) (rows as the loop state z; only 4 rows are read without ``analog``),
            updated in place.
        U: held currents (B,) [mA].
        t0: each lane's start time (B,) [s].
        h: control period [s].
        substeps: RK4 steps per period.
        c: lane constants (N_LANE_CONST, B).
        events: friction events (B, E, 3).
        work: scratch (6, N_LOOP, B) (rows work[5, 0] and work[5, 2] are this function's).
        analog: integrate the analog lanes' filters too (some lane's estimator is analog).
        ctrl: controller rows (B, N_CTRL); read with ``analog``.
        ref: reference spec rows (B, N_REF); read with ``analog``.
        filt: filter blocks (B, N_FB, 4, 4); read with ``analog``.
        ynoise: the sensor noise on the output at the last sample (B,) [output unit]; read with ``analog``.
    """
    B = X.shape[1]
    n = X.shape[0] if analog else N_PLANT
    dt = h / substeps
    k1, k2, k3, k4, xt = work[0], work[1], work[2], work[3], work[4]  # the RK4 stages and the stage state
    amp = work[5, 0]  # the loop's LW_AMP row
    ts = work[5, 2]  # each lane's stage time [s] (the analog filters' reference)
    for j in range(substeps):
        for b in range(B):
            amp[b] = active_amplitude(t0[b] + (j + 0.5) * dt, events[b])
        for stage, (xs, kk, half) in enumerate(((X, k1, 0.5), (xt, k2, 0.5), (xt, k3, 1.0))):
            lane_rhs(xs, amp, U, c, kk, B)
            if analog:
                for b in range(B):  # the stage's time: t0 + j dt, then + dt/2 (as t0 + j dt + 0.5 dt, in this order)
                    ts[b] = t0[b] + j * dt if stage == 0 else (t0[b] + j * dt) + 0.5 * dt
                analog_filter_rhs(xs, ts, ctrl, ref, filt, ynoise, kk, B)
            for i in range(n):
                for b in range(B):
                    xt[i, b] = X[i, b] + half * dt * kk[i, b]
        lane_rhs(xt, amp, U, c, k4, B)
        if analog:
            for b in range(B):
                ts[b] = (t0[b] + j * dt) + dt
            analog_filter_rhs(xt, ts, ctrl, ref, filt, ynoise, k4, B)
        for i in range(n):
            for b in range(B):
                X[i, b] += dt / 6.0 * (k1[i, b] + 2.0 * k2[i, b] + 2.0 * k3[i, b] + k4[i, b])
        for b in range(B):
            X[X_PL, b] = relief(X[X_PL, b], c[LC_PS, b])


def plant_only_arrays(B: int):
    """(ctrl, ref, filt, ynoise) placeholders for :func:`integrate_lanes` without analog filters (never read)."""
    return np.zeros((B, N_CTRL)), np.zeros((B, N_REF)), np.zeros((B, N_FB, MAX_ORDER, MAX_ORDER)), np.zeros(B)


# --- Counter-based Gaussian noise: deterministic whatever the thread layout ---


@jit
def _splitmix64(z):
    z = (z + np.uint64(0x9E3779B97F4A7C15)) & np.uint64(0xFFFFFFFFFFFFFFFF)
    z = ((z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)) & np.uint64(0xFFFFFFFFFFFFFFFF)
    z = ((z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)) & np.uint64(0xFFFFFFFFFFFFFFFF)
    return z ^ (z >> np.uint64(31))


@jit_inline
def noise_uniforms(seed, k, channel):
    """The two uniform variates (u1 in (0, 1], u2 in [0, 1)) of :func:`gaussian`'s sample (seed, step k, channel):
    integer arithmetic only, so a loop over lanes vectorises it."""
    key = _splitmix64(np.uint64(seed) * np.uint64(0x100000001B3) + np.uint64(k) * np.uint64(8) + np.uint64(channel))
    a = _splitmix64(key)
    b = _splitmix64(a)
    u1 = ((a >> np.uint64(11)) + np.uint64(1)) * (1.0 / 9007199254740993.0)  # (0, 1]
    u2 = (b >> np.uint64(11)) * (1.0 / 9007199254740992.0)
    return u1, u2


@jit_inline
def normal_from(u1, u2):
    """Box-Muller: a standard normal sample from the uniforms of :func:`noise_uniforms` (libm's log and cos)."""
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)


@jit
def gaussian(seed, k, channel):
    """Standard normal sample, a pure function of (seed, step k, channel)."""
    u1, u2 = noise_uniforms(seed, k, channel)
    return normal_from(u1, u2)
