"""Slow, independent reference implementations used by the tests.

Nothing here imports the compiled kernels: the plant is written again from
Eq. (1), the Lie derivatives are derived symbolically by sympy, and the plant,
the reference model and the derivative estimator are integrated together, as the
continuous-time systems the paper draws (Eqs. 1, 5, 19, 21, 24), by
``scipy.integrate.solve_ivp``. No filter is discretised here: a reference that
shared the code's discretisation could not see its error (wave 1's ZOH estimator
was biased by O(h) and a ZOH reference agreed with it).
"""

from __future__ import annotations

import functools
import math

import numpy as np
import scipy.signal
import sympy as sp
from scipy.integrate import solve_ivp

from ehss_gym.core.params import PlantParams


@functools.cache
def symbolic_model(order: int):
    """Lambdified (h_0..h_{m-1}, F, G) of the friction-free model, derived by sympy."""
    x1, x2, x3, x4, u = sp.symbols("x1 x2 x3 x4 u", real=True)
    names = PlantParams._fields
    P = sp.symbols(" ".join(names), positive=True)
    p = dict(zip(names, P))
    sv = x4 / sp.sqrt(x4**2 + p["delta_valve"])
    dp = p["P_s"] - sv * x3
    R = dp / sp.sqrt(p["rho"] * sp.sqrt(dp**2 + p["dp_transition"] ** 2))
    Q = p["c_d"] * x4 * R
    f = sp.Matrix([
        x2,
        (p["d_m"] * x3 - p["B"] * x2) / p["J"],
        4 * p["beta"] / p["V_m"] * (Q - p["d_m"] * x2 - p["c_sm"] * x3),
        -x4 / p["tau"],
    ])
    g = sp.Matrix([0, 0, 0, p["K"] / p["tau"]])
    X = sp.Matrix([x1, x2, x3, x4])
    h = [x1] if order == 4 else [x2]
    for _ in range(order - 1):
        h.append((sp.Matrix([h[-1]]).jacobian(X) * f)[0])
    grad = sp.Matrix([h[-1]]).jacobian(X)
    F = (grad * f)[0]
    G = (grad * g)[0]
    args = (x1, x2, x3, x4) + tuple(P)
    return sp.lambdify(args, h, "math"), sp.lambdify(args, F, "math"), sp.lambdify(args, G, "math")


def lie_reference(x, p: PlantParams, order: int):
    """(h list, F, G) at state x from the symbolic derivation."""
    hf, Ff, Gf = symbolic_model(order)
    a = tuple(float(v) for v in x) + tuple(p)
    return hf(*a), Ff(*a), Gf(*a)


def plant_rhs_np(t, x, u, p: PlantParams, friction):
    """Eq. (1) written out again in plain Python (NOTES readings 1-3)."""
    x1, x2, x3, x4 = x
    sv = x4 / math.sqrt(x4 * x4 + p.delta_valve)
    dp = p.P_s - sv * x3
    R = dp / math.sqrt(p.rho * math.sqrt(dp * dp + p.dp_transition**2))
    amp = sum(a for a, t0, t1 in friction if t0 <= t < t1)
    tf = amp * x2 / math.sqrt(x2 * x2 + p.delta_friction)
    return [
        x2,
        (p.d_m * x3 - p.B * x2 - tf) / p.J,
        4 * p.beta / p.V_m * (p.c_d * x4 * R - p.d_m * x2 - p.c_sm * x3),
        (p.K * u - x4) / p.tau,
    ]


def butter_c(order, hz):
    b, a = scipy.signal.butter(order, 2 * math.pi * hz, analog=True)
    return np.asarray(a[::-1][:order] / a[0])


def companion_np(c):
    """(A, b) of the unit-DC-gain state-variable filter z^(m) + c_{m-1} z^(m-1) + ... + c_0 z = c_0 v."""
    m = len(c)
    A = np.zeros((m, m))
    A[:-1, 1:] = np.eye(m - 1)
    A[-1] = -np.asarray(c)
    b = np.zeros(m)
    b[-1] = c[0]
    return A, b


def reference_closed_loop(sc, rtol=1e-12, atol_scale=1e-14):
    """The scenario's closed loop in continuous time, integrated by solve_ivp (Radau, tight tolerances).

    The state is (plant x1..x4, reference model y_d..y_d^(m-1), estimator y_e..y_e^(m-2)); the reference
    model is driven by r(t) and the estimator by the plant output y(t), both continuously. Every control
    period the law (re-implemented in numpy from the same equations) samples this state, and its
    current is held over the period: the paper's analog filters around a digital law. Noise-free.

    Returns:
        (t_k, x_k, w_k) at the control instants: plant states (n_steps + 1, 4) and filter states
        (n_steps + 1, 2m - 1).
    """
    p = sc.plant
    m = sc.order
    h = sc.control_period
    cr = butter_c(m, sc.ref_model_hz)
    ce = butter_c(m - 1, sc.estimator_hz)
    lam = butter_c(m - 1, sc.fr)
    Ar, br = companion_np(cr)
    Ae, be = companion_np(ce)
    out = 0 if m == 4 else 1
    ulim = math.inf if sc.current_limit is None else sc.current_limit

    def rhs(t, w, u):
        x = w[:4]
        dx = plant_rhs_np(t, x, u, p, sc.friction)
        dzr = Ar @ w[4:4 + m] + br * float(sc.reference(t))
        dze = Ae @ w[4 + m:] + be * x[out]
        return np.concatenate([dx, dzr, dze])

    w = np.zeros(4 + m + m - 1)
    w[4] = sc.reference(0.0)
    scale = np.concatenate([[1.0, 1.0, p.P_s, p.K], np.full(2 * m - 1, 1.0)])
    ws = [w.copy()]
    ts = [0.0]
    for k in range(sc.n_steps):
        t = k * h
        x, zr, ze = w[:4], w[4:4 + m], w[4 + m:]
        r = float(sc.reference(t))
        y = x[out]
        yd = list(zr) + [cr[0] * r - cr @ zr]
        ye = [y] + list(ze[1:]) + [ce[0] * y - ce @ ze]
        e = [ye[i] - yd[i] for i in range(m)]
        s = e[m - 1] + sum(lam[i] * e[i] for i in range(m - 1))
        _, F, G = lie_reference(x, p, m)
        psi = F - yd[m] + sum(lam[i] * e[i + 1] for i in range(m - 1))
        u = sontag_reference(psi, G, s, sc.n, sc.sigma, sc.smoothing)
        u = min(max(u, -ulim), ulim)
        sol = solve_ivp(rhs, (t, t + h), w, method="Radau", rtol=rtol, atol=atol_scale * scale, args=(u,))
        w = sol.y[:, -1]
        assert abs(w[2]) < p.P_s, "the relief valves would act: this reference does not model them"
        ws.append(w.copy())
        ts.append(t + h)
    W = np.array(ws)
    return np.array(ts), W[:, :4], W[:, 4:]


def sontag_reference(psi, G, s, n, sigma, w):
    """Sontag's formula in its textbook form u = -(a + sqrt(a^2 + b^4)) / b with python floats,
    plus the smooth-sign variant (s / sqrt(s^2 + w^2) instead of sign(s))."""
    if s == 0 and w == 0:
        return 0.0
    a = (s / sigma) ** (n - 1) * psi / sigma
    b = (s / sigma) ** (n - 1) * G / sigma
    if w == 0:
        return -(a + math.sqrt(a * a + b**4)) / b
    # the smoothed law is defined through psi/G and |b| (see ehss_gym.core.laws)
    sg = s / math.sqrt(s * s + w * w)
    return -psi / G - sg * math.copysign(1.0, G) * math.hypot(psi / G, abs(b))
