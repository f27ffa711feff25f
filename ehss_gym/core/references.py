"""The reference r(t), compiled: one kernel per family, the dispatch built from the table, and the reference shaper.

A family (a row of :data:`ehss_gym.core.registry.REFERENCE_FAMILIES`) is its kernel here, ``name(t, spec, r)``: r(t)
from the offset ``r`` and the family's parameters in the spec row (layout ``R_*``), and its builder in
:mod:`ehss_gym.core.signals`. :func:`reference_value` calls the kernel of the row's code (``spec[R_KIND]``), so a batch
of scenarios can mix families. The position task's reference shaper (:func:`shape_reference`) turns r into a
reference the valve can follow, ahead of the reference model.
"""

from __future__ import annotations

import math

from .jit import dispatch, jit
from .layout import (
    MAX_SINES,
    R_A1,
    R_KIND,
    R_MS0,
    R_OFFSET,
    R_P1,
    R_T0,
    R_T1,
    R_TAB0,
    R_TAB_N,
    R_W1,
    R_W_END,
    Z_SHAPE,
)
from .registry import REFERENCE_FAMILIES


@jit
def sine_value(t, spec, r):
    """offset + A sin(w t + phi)."""
    return r + spec[R_A1] * math.sin(spec[R_W1] * t + spec[R_P1])


@jit
def step_value(t, spec, r):
    """offset + A from t_step on."""
    if t >= spec[R_T0]:
        r += spec[R_A1]
    return r


@jit
def chirp_value(t, spec, r):
    """Linear frequency sweep w1 -> w_end over [t0, t1], then constant w_end."""
    t0 = spec[R_T0]
    t1 = spec[R_T1]
    w0 = spec[R_W1]
    w1 = spec[R_W_END]
    if t < t0:
        ph = w0 * (t - t0)
    elif t < t1:
        tau = t - t0
        ph = w0 * tau + 0.5 * (w1 - w0) / (t1 - t0) * tau * tau
    else:
        ph = 0.5 * (w0 + w1) * (t1 - t0) + w1 * (t - t1)
    return r + spec[R_A1] * math.sin(ph + spec[R_P1])


@jit
def multisine_value(t, spec, r):
    """offset + sum_i A_i sin(w_i t + phi_i) over the MAX_SINES component slots (unused ones are zero)."""
    for i in range(MAX_SINES):
        j = R_MS0 + 3 * i
        r += spec[j] * math.sin(spec[j + 1] * t + spec[j + 2])
    return r


@jit
def table_value(t, spec, r):
    """offset + linear interpolation in a table row's samples (layout R_TAB*); the end values held outside them."""
    n = int(spec[R_TAB_N])
    t0 = R_TAB0
    r0 = R_TAB0 + n
    if t <= spec[t0]:
        return r + spec[r0]
    if t >= spec[t0 + n - 1]:
        return r + spec[r0 + n - 1]
    lo = 0
    hi = n - 1
    while hi - lo > 1:  # bisection: spec[t0 + lo] <= t < spec[t0 + hi]
        mid = (lo + hi) // 2
        if spec[t0 + mid] <= t:
            lo = mid
        else:
            hi = mid
    w = (t - spec[t0 + lo]) / (spec[t0 + hi] - spec[t0 + lo])
    return r + (spec[r0 + lo] + w * (spec[r0 + hi] - spec[r0 + lo]))


# --- The reference shaper (position task): a reference the valve can follow ---------------------------------


@jit
def shape_reference(z, k, h, r, a_max, p0):
    r"""The reference shaper (position task): the shaped reference p_k at sample k, which drives the reference model.

    p is a double integrator, p'' = clip(r_a, +-a/2) + fhan(p - r, p' - r_v, a/2, h), with r_v, r_a the
    reference's first and second differences: it follows r exactly where |r''| <= a/2 (then p - r and
    p' - r_v stay 0) and closes the gap left by a jump of r time-optimally, so |p''| <= a = ``a_max``
    [rad/s^2] always. Han's fhan (:func:`fhan`) is the discrete time-optimal law for a double integrator.
    At k = 0 it starts at rest at ``p0`` (the measured output with a bumpless start, else r(0)). The state
    z[Z_SHAPE:Z_SHAPE+4] = (p_k, p'_k, r_{k-1}, r_v,k-1) is advanced to k + 1 here (docs/MODEL.md, "Reference
    shaper").
    """
    if k == 0:  # at rest at p0, r_{-1} = r_0
        z[Z_SHAPE] = p0
        z[Z_SHAPE + 1] = 0.0
        z[Z_SHAPE + 2] = r
        z[Z_SHAPE + 3] = 0.0
    p = z[Z_SHAPE]
    pv = z[Z_SHAPE + 1]
    rv = (r - z[Z_SHAPE + 2]) / h
    ra = (rv - z[Z_SHAPE + 3]) / h
    half = 0.5 * a_max
    acc = fhan(p - r, pv - rv, half, h) + (ra if -half <= ra <= half else (half if ra > 0.0 else -half))
    # (p, p') at t_k is returned; the state moves on to t_{k+1} (Euler, as Han's tracking differentiator)
    z[Z_SHAPE] = p + h * pv
    z[Z_SHAPE + 1] = pv + h * acc
    z[Z_SHAPE + 2] = r
    z[Z_SHAPE + 3] = rv
    return p


@jit
def fhan(x1, x2, r, h):
    """Han's time-optimal synthesis for the discrete double integrator x1' = x2, x2' = u, |u| <= r, period h.

    Drives (x1, x2) to 0 in finite time without overshoot or chattering (J. Han, "From PID to active disturbance
    rejection control", IEEE TIE 56(3), 2009, Eq. 8).
    """
    d = r * h * h
    a0 = h * x2
    y = x1 + a0
    a1 = math.sqrt(d * (d + 8.0 * abs(y)))
    a2 = a0 + _sgn(y) * (a1 - d) / 2.0
    sy = (_sgn(y + d) - _sgn(y - d)) / 2.0
    a = (a0 + y - a2) * sy + a2
    sa = (_sgn(a + d) - _sgn(a - d)) / 2.0
    return -r * (a / d - _sgn(a)) * sa - r * _sgn(a)


@jit
def _sgn(x):
    return 1.0 if x > 0.0 else (-1.0 if x < 0.0 else 0.0)


reference_value = dispatch(
    "reference_value", ("t", "spec"), [globals()[row.kernel] for row in REFERENCE_FAMILIES], __name__,
    code="kind", prefix=(f"kind = int(spec[{R_KIND}])", f"r = spec[{R_OFFSET}]"), local=("kind", "r"),
    doc="r(t) for a spec row [output unit: rad/s (velocity) or rad (position)]; NaN for an unknown family.")

__all__ = ["reference_value", "shape_reference", "fhan", "sine_value", "step_value", "chirp_value", "multisine_value",
           "table_value"]
