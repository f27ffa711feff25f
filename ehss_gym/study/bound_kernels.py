r"""Compiled kernels of the step bound (:mod:`ehss_gym.study.bound`): RK4 with a held current, and the output's
exact sensitivities to the current profile.

The optimiser core is generic over a model: a code (``MODEL_*``) whose pair of functions gives the state's rate
``rhs(x, u, a, p, dx)`` and its Jacobians ``jac(x, u, a, p, A, b)`` (A = d rhs/dx, b = d rhs/du), with ``a`` a
per-step scalar held over the step (the plant's friction amplitude). The EHSS plant's ``rhs`` is
:func:`ehss_gym.core.physics.plant_rhs` with the friction torque formed exactly as
:func:`ehss_gym.core.physics.integrate_lanes` forms it, so a trajectory here is the simulator's to the last bit
(tests/test_bound.py checks it); its Jacobian is built from the physics module's own derivative functions
(``orifice_root_prime``, ``dsigm``) and checked against central differences of ``plant_rhs``. The first-order
lag is the closed-form reference case of the tests, run through the same code.

The sensitivities differentiate exactly what the forward pass computes (the RK4 stages, and the relief valve's
projection of x3 onto [-P_s, P_s], whose derivative is 0 where it clips), so they are those of the discretised
plant, not an approximation of the continuous one's.
"""

from __future__ import annotations

import math

import numpy as np

from ehss_gym.core.layout import X_AV, X_OMEGA, X_PL, X_THETA
from ehss_gym.core.params import P_B, P_BETA, P_CD, P_CSM, P_DF, P_DM, P_DPT, P_DV, P_J, P_K, P_PS, P_RHO, P_TAU, P_VM
from ehss_gym.core.physics import dsigm, jit, orifice_root, orifice_root_prime, plant_rhs, relief, sigm


@jit
def ehss_rhs(x, u, a, p, dx):
    """Eq. (1) for current u [mA] with the friction events' amplitude ``a`` [N*m] (the simulator's torque)."""
    plant_rhs(x, u, a * sigm(x[X_OMEGA], p[P_DF]), p, dx)


@jit
def ehss_jacobian(x, u, a, p, A, b):
    """A = d x'/d x (4 x 4) and b = d x'/d u (4,) of :func:`ehss_rhs` at (x, u)."""
    C = 4.0 * p[P_BETA] / p[P_VM]
    x4 = x[X_AV]
    sv = sigm(x4, p[P_DV])
    dp = p[P_PS] - sv * x[X_PL]
    R = orifice_root(dp, p[P_RHO], p[P_DPT])
    Rp = orifice_root_prime(dp, p[P_RHO], p[P_DPT])
    q3 = -p[P_CD] * x4 * Rp * sv
    q4 = p[P_CD] * (R - x4 * Rp * dsigm(x4, p[P_DV]) * x[X_PL])
    for i in range(4):
        b[i] = 0.0
        for j in range(4):
            A[i, j] = 0.0
    A[X_THETA, X_OMEGA] = 1.0
    A[X_OMEGA, X_OMEGA] = -(p[P_B] + a * dsigm(x[X_OMEGA], p[P_DF])) / p[P_J]
    A[X_OMEGA, X_PL] = p[P_DM] / p[P_J]
    A[X_PL, X_OMEGA] = -C * p[P_DM]
    A[X_PL, X_PL] = C * (q3 - p[P_CSM])
    A[X_PL, X_AV] = C * q4
    A[X_AV, X_AV] = -1.0 / p[P_TAU]
    b[X_AV] = p[P_K] / p[P_TAU]


# The models of the optimiser core: a code and its two functions. The core calls them through model_rhs and
# model_jac (a branch on the code) rather than taking the functions as arguments: numba cannot cache a kernel
# with a function-typed argument on disk, and every new process would recompile it (~10 s).
MODEL_EHSS = 0  # the EHSS plant, Eq. (1): ehss_rhs, ehss_jacobian
MODEL_LAG = 1  # a first-order lag y' = (k u - y) / T, p = (k, T): the closed-form reference case of the tests
MODELS = ("ehss", "lag")


@jit
def lag_rhs(x, u, a, p, dx):
    """y' = (k u - y) / T with p = (k [output unit per unit of u], T [s])."""
    dx[0] = (p[0] * u - x[0]) / p[1]


@jit
def lag_jacobian(x, u, a, p, A, b):
    """A = -1/T, b = k/T of :func:`lag_rhs`."""
    A[0, 0] = -1.0 / p[1]
    b[0] = p[0] / p[1]


@jit
def model_rhs(kind, x, u, a, p, dx):
    """The rate of model ``kind`` (MODEL_*)."""
    if kind == MODEL_EHSS:
        ehss_rhs(x, u, a, p, dx)
    else:
        lag_rhs(x, u, a, p, dx)


@jit
def model_jac(kind, x, u, a, p, A, b):
    """The Jacobians of model ``kind`` (MODEL_*)."""
    if kind == MODEL_EHSS:
        ehss_jacobian(x, u, a, p, A, b)
    else:
        lag_jacobian(x, u, a, p, A, b)


@jit
def rk4_step(x, u, a, dt, p, kind, clip_i, clip_v, k):
    """One RK4 step of model ``kind`` with u held, in place; then x[clip_i] projected onto [-clip_v, clip_v] (none if
    clip_i < 0). Returns True if the projection acted. ``k`` is scratch (5, n). The same operations, in the same
    order, as :func:`ehss_gym.core.physics.integrate_lanes` with one substep."""
    n = x.shape[0]
    k1, k2, k3, k4, xt = k[0], k[1], k[2], k[3], k[4]
    model_rhs(kind, x, u, a, p, k1)
    for i in range(n):
        xt[i] = x[i] + 0.5 * dt * k1[i]
    model_rhs(kind, xt, u, a, p, k2)
    for i in range(n):
        xt[i] = x[i] + 0.5 * dt * k2[i]
    model_rhs(kind, xt, u, a, p, k3)
    for i in range(n):
        xt[i] = x[i] + dt * k3[i]
    model_rhs(kind, xt, u, a, p, k4)
    for i in range(n):
        x[i] += dt / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
    if clip_i >= 0:
        v = relief(x[clip_i], clip_v)
        if v != x[clip_i]:
            x[clip_i] = v
            return True
    return False


@jit
def control_at(u, idx, u_hold, n):
    """The current of RK4 step n: u[idx[n]] on the optimised window, ``u_hold`` where idx[n] < 0."""
    j = idx[n]
    return u[j] if j >= 0 else u_hold


@jit
def simulate_profile(u, idx, u_hold, x0, dt, p, amps, kind, clip_i, clip_v, X, clipped):
    """Integrate from ``x0`` over len(amps) RK4 steps of ``dt`` [s]: X (n_steps + 1, n) the states, ``clipped``
    (n_steps,) where the projection acted. Returns the number of steps done before a non-finite state (the
    states past it are left as they were), len(amps) when none."""
    n_steps = amps.shape[0]
    k = np.empty((5, x0.shape[0]))
    for i in range(x0.shape[0]):
        X[0, i] = x0[i]
    x = x0.copy()
    for s in range(n_steps):
        clipped[s] = rk4_step(x, control_at(u, idx, u_hold, s), amps[s], dt, p, kind, clip_i, clip_v, k)
        for i in range(x.shape[0]):
            if not math.isfinite(x[i]):
                return s
            X[s + 1, i] = x[i]
    return n_steps


@jit
def _matvec_add(A, v, out, scale):
    """out += scale * A v."""
    n = v.shape[0]
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += A[i, j] * v[j]
        out[i] += scale * acc


@jit
def rk4_jacobians(x, u, a, dt, p, kind, Phi, Gam, k, D, A, b, t):
    """Phi = d x_{n+1}/d x_n (n x n) and Gam = d x_{n+1}/d u (n,) of the RK4 step from ``x`` (before any
    projection), by the chain rule through the stages: with A_i, b_i the model's Jacobians at stage i,
    D_1 = A_1, D_i = A_i (I + c_i dt D_{i-1}); g_1 = b_1, g_i = b_i + c_i dt A_i g_{i-1} (c = 1/2, 1/2, 1);
    Phi = I + dt/6 (D_1 + 2 D_2 + 2 D_3 + D_4), Gam = dt/6 (g_1 + 2 g_2 + 2 g_3 + g_4).
    ``k`` (5, n), ``D`` (2, n, n), ``A`` (n, n), ``b`` (n,), ``t`` (3, n) are scratch."""
    n = x.shape[0]
    xs = k[4]
    Dp, Dn = D[0], D[1]
    gp, gn, tmp = t[0], t[1], t[2]
    for i in range(n):
        Gam[i] = 0.0
        for j in range(n):
            Phi[i, j] = 1.0 if i == j else 0.0
    for stage in range(4):
        c = 0.0 if stage == 0 else (1.0 if stage == 3 else 0.5)
        if stage == 0:
            for i in range(n):
                xs[i] = x[i]
        else:
            for i in range(n):
                xs[i] = x[i] + c * dt * k[stage - 1, i]
        model_rhs(kind, xs, u, a, p, k[stage])
        model_jac(kind, xs, u, a, p, A, b)
        for i in range(n):  # D_i = A_i (I + c dt D_{i-1}), g_i = b_i + c dt A_i g_{i-1}
            for j in range(n):
                acc = A[i, j]
                if stage > 0:
                    for m in range(n):
                        acc += c * dt * A[i, m] * Dp[m, j]
                Dn[i, j] = acc
            gn[i] = b[i]
        if stage > 0:
            for i in range(n):
                tmp[i] = gp[i]
            _matvec_add(A, tmp, gn, c * dt)
        wgt = dt / 6.0 if stage == 0 or stage == 3 else dt / 3.0
        for i in range(n):
            Gam[i] += wgt * gn[i]
            gp[i] = gn[i]
            for j in range(n):
                Phi[i, j] += wgt * Dn[i, j]
                Dp[i, j] = Dn[i, j]


@jit
def output_sensitivity(u, idx, rs, u_hold, x0, dt, p, amps, kind, clip_i, clip_v, out_i, X, clipped, S):
    """The trajectory X of the profile ``u`` and the output's sensitivities on a grid of rows:
    S[r, j] = d y_(r rs) / d u_j for the rows r = 0, 1, ... (every ``rs`` steps, and the last step), with
    y = X[:, out_i]. ``rs`` divides the control interval, so the control is constant between two rows: there the
    step Jacobians are multiplied into one transition (P) and one input column (G), and the full sensitivity
    M (n x n_ctrl) is updated once per row: M <- P M, then M[:, j] += G for the row's control j. Returns the
    number of steps done before a non-finite state (len(amps) when none)."""
    n_steps = amps.shape[0]
    done = simulate_profile(u, idx, u_hold, x0, dt, p, amps, kind, clip_i, clip_v, X, clipped)
    if done < n_steps:
        return done
    n = x0.shape[0]
    nc = u.shape[0]
    M = np.zeros((n, nc))
    col = np.zeros(n)
    P = np.empty((n, n))
    G = np.empty(n)
    Pn = np.empty((n, n))
    Phi = np.empty((n, n))
    Gam = np.empty(n)
    k = np.empty((5, n))
    D = np.empty((2, n, n))
    A = np.empty((n, n))
    b = np.empty(n)
    t = np.empty((3, n))
    for c in range(nc):
        S[0, c] = 0.0
    row = 0
    start = 0
    while start < n_steps:
        end = min(start + rs, n_steps)
        for i in range(n):
            G[i] = 0.0
            for j in range(n):
                P[i, j] = 1.0 if i == j else 0.0
        for s in range(start, end):
            rk4_jacobians(X[s], control_at(u, idx, u_hold, s), amps[s], dt, p, kind, Phi, Gam, k, D, A, b, t)
            if clipped[s]:
                for m in range(n):
                    Phi[clip_i, m] = 0.0
                Gam[clip_i] = 0.0
            for i in range(n):  # P <- Phi P, G <- Phi G + Gam
                for j in range(n):
                    acc = 0.0
                    for m in range(n):
                        acc += Phi[i, m] * P[m, j]
                    Pn[i, j] = acc
            for i in range(n):
                col[i] = Gam[i]
            _matvec_add(Phi, G, col, 1.0)
            for i in range(n):
                G[i] = col[i]
                for j in range(n):
                    P[i, j] = Pn[i, j]
        j = idx[start]
        hi = nc if j < 0 else j + 1
        for c in range(hi):  # M <- P M for the controls that acted before this stretch and its own
            for i in range(n):
                col[i] = M[i, c]
            for i in range(n):
                acc = 0.0
                for m in range(n):
                    acc += P[i, m] * col[m]
                M[i, c] = acc
        if j >= 0:
            for i in range(n):
                M[i, j] += G[i]
        row += 1
        for c in range(nc):
            S[row, c] = M[out_i, c]
        start = end
    return n_steps

