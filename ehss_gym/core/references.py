"""The reference r(t), compiled: one kernel per family and the dispatch built from the table.

A family (a row of :data:`ehss_gym.core.registry.REFERENCE_FAMILIES`) is its kernel here, ``name(t, spec, r)``: r(t)
from the offset ``r`` and the family's parameters in the spec row (layout ``R_*``), and its builder in
:mod:`ehss_gym.core.signals`. :func:`reference_value` calls the kernel of the row's code (``spec[R_KIND]``), so a batch
of scenarios can mix families.
"""

from __future__ import annotations

import math

from .jit import dispatch, jit_inline
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
)
from .registry import REFERENCE_FAMILIES


@jit_inline
def sine_value(t, spec, r):
    """offset + A sin(w t + phi)."""
    return r + spec[R_A1] * math.sin(spec[R_W1] * t + spec[R_P1])


@jit_inline
def step_value(t, spec, r):
    """offset + A from t_step on."""
    if t >= spec[R_T0]:
        r += spec[R_A1]
    return r


@jit_inline
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


@jit_inline
def multisine_value(t, spec, r):
    """offset + sum_i A_i sin(w_i t + phi_i) over the MAX_SINES component slots (unused ones are zero)."""
    for i in range(MAX_SINES):
        j = R_MS0 + 3 * i
        r += spec[j] * math.sin(spec[j + 1] * t + spec[j + 2])
    return r


@jit_inline
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


reference_value = dispatch(
    "reference_value", ("t", "spec"), [globals()[row.kernel] for row in REFERENCE_FAMILIES], __name__,
    code="kind", prefix=(f"kind = int(spec[{R_KIND}])", f"r = spec[{R_OFFSET}]"), local=("kind", "r"),
    doc="r(t) for a spec row [output unit: rad/s (velocity) or rad (position)]; NaN for an unknown family.")

__all__ = ["reference_value", "sine_value", "step_value", "chirp_value", "multisine_value",
           "table_value"]
