"""The output-derivative estimators: one pair of kernels per estimator, and the digital filters they share.

The controller needs y, y', ..., y^(m-1) at each sample. An estimator (a row of
:data:`ehss_gym.core.registry.ESTIMATORS`) is its kernel that writes them into the info row at the sample
(``sense``) and, if it keeps a state, its kernel that advances that state over the period (``advance``);
:func:`estimate_derivatives` and :func:`advance_estimator` call the kernels of the estimator's code. Kernels take
any of ``z, m, filt, xm, hd, y_meas, info`` by these names: the loop state, the relative degree, the filter block,
the measured state, the model's output derivatives of the measured state (y, y', ... = L_f^i h(x_meas)), the
measured output, the info row.

- the paper's state-variable filter (SVF; "foh", "zoh", "analog"): the filter's outputs, its top derivative from its
  equation (:func:`filter_outputs`); advanced digitally (:func:`advance_filter`) or, "analog", by the plant's RK4;
- "state": the model's Lie derivatives of the measured state, ``hd``;
- "eso": the observer's velocity w_hat and acceleration a_m + d_hat (the model's acceleration of the measured state
  plus the estimated disturbance); the top derivative is the state's (L_f^(m-1) h).

See docs/MODEL.md, "Digital filters" and "Estimators".
"""

from __future__ import annotations

from .jit import dispatch, jit, jit_inline, jit_noalloc
from .layout import (
    FB_D_OBS,
    FB_E_OBS,
    FB_PHI_EST,
    FB_PHI_OBS,
    FB_PHI_REF,
    FB_VEC,
    FB_VEC2,
    FBV_C_EST,
    FBV_D_EST,
    FBV_E_EST,
    FBV_E_REF,
    I_AM,
    I_RM,
    I_XM,
    I_YE,
    X_OMEGA,
    Z_EST,
    Z_OBS,
    Z_REF,
)
from .registry import ESTIMATORS


@jit
def filter_outputs(z, off, order, c, d, v, out, o):
    """A digital filter's outputs at the sample: out[o + i] = z_i = w_i + d_i v (i < order); returns z^(order).

    ``z[off:off+order]`` is the filter state w (layout FB_*: D = 0 for "zoh" and "analog", where w is the
    state itself), v the input at the sample; the top derivative comes from the filter's own equation,
    z^(order) = c_0 v - sum_i c_i z_i, with the same v (docs/MODEL.md, "Digital filters").
    """
    top = c[0] * v
    for i in range(order):
        zi = z[off + i] + d[i] * v
        out[o + i] = zi
        top -= c[i] * zi
    return top


@jit
def advance_filter(z, off, order, phi, gam, v, tmp):
    """z[off:off+order] <- Phi z + E v: one step of a digital filter; ``tmp`` is scratch."""
    for i in range(order):
        acc = gam[i] * v
        for j in range(order):
            acc += phi[i, j] * z[off + j]
        tmp[i] = acc
    for i in range(order):
        z[off + i] = tmp[i]


@jit_inline
def svf_sense(z, m, filt, y_meas, info):
    """The state-variable filter's outputs y_e, ..., y_e^(m-2) at the sample and its top derivative y_e^(m-1)."""
    info[I_YE + m - 1] = filter_outputs(z, Z_EST, m - 1, filt[FB_VEC, FBV_C_EST], filt[FB_VEC2, FBV_D_EST], y_meas,
                                        info, I_YE)


@jit_inline
def svf_advance(z, m, filt, info, hd):
    """The state-variable filter over the period, driven by the measured output at the sample (``hd`` is scratch)."""
    advance_filter(z, Z_EST, m - 1, filt[FB_PHI_EST], filt[FB_VEC, FBV_E_EST], info[I_YE], hd)


@jit_inline
def state_sense(m, hd, info):
    """The model's Lie derivatives of the measured state: y^(i) = L_f^i h(x_meas)."""
    for i in range(1, m):
        info[I_YE + i] = hd[i]


@jit_inline
def eso_sense(z, m, filt, xm, hd, info):
    """The observer's velocity and acceleration (model acceleration plus the estimated disturbance); the top
    derivative is the state's."""
    am = info[I_AM]
    wm = xm[X_OMEGA]
    dd = filt[FB_D_OBS]
    w_hat = z[Z_OBS] + dd[0, 0] * am + dd[0, 1] * wm
    d_hat = z[Z_OBS + 1] + dd[1, 0] * am + dd[1, 1] * wm
    if m == 4:
        info[I_YE + 1] = w_hat
        info[I_YE + 2] = am + d_hat
        info[I_YE + 3] = hd[3]
    else:
        info[I_YE + 1] = am + d_hat
        info[I_YE + 2] = hd[2]


@jit_inline
def eso_advance(z, filt, info):
    """The observer over the period, driven by the model acceleration and the measured velocity at the sample."""
    am = info[I_AM]
    wm = info[I_XM + X_OMEGA]
    phi = filt[FB_PHI_OBS]
    e = filt[FB_E_OBS]
    w0 = phi[0, 0] * z[Z_OBS] + phi[0, 1] * z[Z_OBS + 1] + e[0, 0] * am + e[0, 1] * wm
    w1 = phi[1, 0] * z[Z_OBS] + phi[1, 1] * z[Z_OBS + 1] + e[1, 0] * am + e[1, 1] * wm
    z[Z_OBS] = w0
    z[Z_OBS + 1] = w1


_sense = dispatch("_sense", ("est", "z", "m", "filt", "xm", "hd", "y_meas", "info"),
                  [globals()[row.sense] for row in ESTIMATORS], __name__, code="est", otherwise="None",
                  doc="The sense kernel of estimator code ``est``.")

advance_estimator = dispatch(
    "advance_estimator", ("est", "z", "m", "filt", "info", "hd"),
    [None if row.advance is None else globals()[row.advance] for row in ESTIMATORS], __name__, code="est",
    otherwise="None", doc="Advance the state of estimator code ``est`` over the period (none for an estimator "
                          "without one, or whose filters the plant's integrator advances).")

@jit_inline
def advance_filters(z, m, est, filt, info, tmp):
    """Advance the digital filters over the period, w <- Phi w + E v, with the inputs v this sample recorded in
    ``info``: the reference model (its input I_RM) and the state of estimator code ``est`` (the measured output I_YE
    for the SVF, the model acceleration and the measured velocity I_AM, I_XM + 1 for the observer). ``tmp`` is
    scratch (>= m)."""
    advance_filter(z, Z_REF, m, filt[FB_PHI_REF], filt[FB_VEC, FBV_E_REF], info[I_RM], tmp)
    advance_estimator(est, z, m, filt, info, tmp)


@jit_noalloc
def estimate_derivatives(z, m, est, filt, xm, hd, y_meas, info):
    """info[I_YE + i], i < m: the measured output and the estimated y', ..., y^(m-1) of estimator code ``est``."""
    _sense(est, z, m, filt, xm, hd, y_meas, info)
    info[I_YE] = y_meas


__all__ = ["estimate_derivatives", "advance_filters", "advance_estimator", "filter_outputs", "advance_filter",
           "svf_sense", "svf_advance", "state_sense", "eso_sense", "eso_advance"]
