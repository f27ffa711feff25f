r"""The EHSS plant, Eq. (1), and its Lie derivatives, as pure compiled functions.

Model (NOTES.md items 1-3; friction T_f from the event list, Eq. 25)::

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
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from .layout import F_AMP, F_END, F_START, X_AV, X_OMEGA, X_PL, X_THETA
from .params import P_B, P_BETA, P_CD, P_CSM, P_DF, P_DM, P_DPT, P_DV, P_J, P_K, P_PS, P_RHO, P_TAU, P_VM

jit = nb.njit(cache=True, fastmath=False, error_model="numpy")
# The hot per-period kernels (lanes, controller, env step) are compiled without numba's reference-counting
# runtime (NRT): they never allocate, and with NRT every array view they take (z[b], work[0], events[b], ...)
# costs an atomic incref/decref pair, measured at ~40 % of an env step. Without NRT such a view is a plain
# struct; a kernel that tries to allocate fails to compile ("NRT required but not enabled") rather than
# misbehaving. ``_nrt`` is numba's (underscore) flag for this; 0.68 honours it.
jit_noalloc = nb.njit(cache=True, fastmath=False, error_model="numpy", _nrt=False)


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
        if events[i, F_START] <= t < events[i, F_END]:
            amp += events[i, F_AMP]
    return amp


@jit
def friction_torque(t, omega, events, delta_friction):
    """Coulomb friction torque [N*m] of all events active at time t.

    An event (A, t_start, t_end) is active for t_start <= t < t_end.
    """
    return active_amplitude(t, events) * (omega / math.sqrt(omega * omega + delta_friction))


@jit
def plant_rhs(x, u, tf, p, dx):
    """Write x' of Eq. (1) into ``dx`` for current u [mA] and friction tf [N*m].

    The expression shapes match :func:`lane_rhs` exactly, so the scalar and
    lane integrators agree to the last bit.
    """
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


@jit_noalloc
def integrate_plant(x, u, t0, h, substeps, p, events, work):
    """Advance the plant state ``x`` in place over [t0, t0+h] with u held (ZOH).

    Classic RK4 with ``substeps`` equal steps. The friction events are switched
    on the substep grid: the amplitude is taken at each substep's midpoint and
    held over it, so an edge on the grid is exact and one between grid points
    is resolved to within a substep. (Evaluating it per RK4 stage would let
    the step just before an edge see the new value at its end point.)
    ``work`` is scratch of shape (5, 4).
    """
    dt = h / substeps
    k1, k2, k3, k4, xt = work[0], work[1], work[2], work[3], work[4]  # the RK4 stages and the stage state
    n = x.shape[0]
    for j in range(substeps):
        amp = active_amplitude(t0 + (j + 0.5) * dt, events)
        plant_rhs(x, u, amp * (x[X_OMEGA] / math.sqrt(x[X_OMEGA] * x[X_OMEGA] + p[P_DF])), p, k1)
        for i in range(n):
            xt[i] = x[i] + 0.5 * dt * k1[i]
        plant_rhs(xt, u, amp * (xt[X_OMEGA] / math.sqrt(xt[X_OMEGA] * xt[X_OMEGA] + p[P_DF])), p, k2)
        for i in range(n):
            xt[i] = x[i] + 0.5 * dt * k2[i]
        plant_rhs(xt, u, amp * (xt[X_OMEGA] / math.sqrt(xt[X_OMEGA] * xt[X_OMEGA] + p[P_DF])), p, k3)
        for i in range(n):
            xt[i] = x[i] + dt * k3[i]
        plant_rhs(xt, u, amp * (xt[X_OMEGA] / math.sqrt(xt[X_OMEGA] * xt[X_OMEGA] + p[P_DF])), p, k4)
        for i in range(n):
            x[i] += dt / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
        x[X_PL] = relief(x[X_PL], p[P_PS])


# Lane constants: per-scenario coefficients laid out (N_LANE_CONST, lanes) so the
# inner loop over lanes reads contiguous memory and vectorises.
LC_DMJ, LC_BJ, LC_IJ, LC_C, LC_CD, LC_PS, LC_RHO, LC_DPT2, LC_KT, LC_IT, LC_DV, LC_DF, LC_CSM, LC_DM = range(14)
N_LANE_CONST = 14


@jit
def lane_constants(P, out):
    """Fill ``out`` (N_LANE_CONST, B) from plant parameter rows ``P`` (B, n_params)."""
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
    x3 = x[X_PL]
    x4 = x[X_AV]
    J = p[P_J]
    B = p[P_B]
    dm = p[P_DM]
    C = 4.0 * p[P_BETA] / p[P_VM]
    sv = sigm(x4, p[P_DV])
    dp = p[P_PS] - sv * x3
    R = orifice_root(dp, p[P_RHO], p[P_DPT])
    Rp = orifice_root_prime(dp, p[P_RHO], p[P_DPT])
    Q = p[P_CD] * x4 * R
    Q3 = -p[P_CD] * x4 * Rp * sv
    Q4 = p[P_CD] * (R - x4 * Rp * dsigm(x4, p[P_DV]) * x3)
    f2 = (dm * x3 - B * x2) / J
    f3 = C * (Q - dm * x2 - p[P_CSM] * x3)
    f4 = -x4 / p[P_TAU]
    h2 = (dm * f3 - B * f2) / J
    F = dm / J * C * (Q3 * f3 + Q4 * f4 - dm * f2 - p[P_CSM] * f3) - B / J * h2
    G = dm / J * C * Q4 * p[P_K] / p[P_TAU]
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


# --- Counter-based Gaussian noise: deterministic whatever the thread layout ---


@jit
def _splitmix64(z):
    z = (z + np.uint64(0x9E3779B97F4A7C15)) & np.uint64(0xFFFFFFFFFFFFFFFF)
    z = ((z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)) & np.uint64(0xFFFFFFFFFFFFFFFF)
    z = ((z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)) & np.uint64(0xFFFFFFFFFFFFFFFF)
    return z ^ (z >> np.uint64(31))


@jit
def gaussian(seed, k, channel):
    """Standard normal sample, a pure function of (seed, step k, channel)."""
    key = _splitmix64(np.uint64(seed) * np.uint64(0x100000001B3) + np.uint64(k) * np.uint64(8) + np.uint64(channel))
    a = _splitmix64(key)
    b = _splitmix64(a)
    u1 = ((a >> np.uint64(11)) + np.uint64(1)) * (1.0 / 9007199254740993.0)  # (0, 1]
    u2 = (b >> np.uint64(11)) * (1.0 / 9007199254740992.0)
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)
