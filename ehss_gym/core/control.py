r"""Lyapunov redesign by Sontag's formula on V = (s/sigma)^n / n, and one control period.

Derivation (NOTES items 9, 10, 14). With the combined error s and
s' = psi + G u, the CLF V = (s/sigma)^n / n has V' = a + b u with::

    a = (s/sigma)^(n-1) psi / sigma,    b = (s/sigma)^(n-1) G / sigma.

Sontag's universal formula u = -(a + sqrt(a^2 + b^4)) / b (u = 0 if b = 0)
gives V' = -sqrt(a^2 + b^4) < 0. Since a and b share (s/sigma)^(n-1)::

    u = -psi/G - sign(s) sign(G) hypot(psi/G, |s/sigma|^(n-1) |G| / sigma)

which never forms s^(4n-4). |s/sigma|^(n-1) is formed by repeated multiplication
(cheap, and correctly scaled whenever it is a normal float), falling back to log
space when it over- or underflows, so nothing overflows unless the current itself
does. sigma = 1 is the paper's law.

Smoothing (not in the paper; the paper's "future work" on chattering): sign(s)
is replaced by s / sqrt(s^2 + w^2), the same shape as the paper's Eq. (2)
sigmoid with delta = w^2. w = 0 is the plain law. The sign of V' is unchanged,
so V still decreases wherever s != 0, only more gently inside |s| < w; at
s = 0 the smoothed law is the equivalent control -psi/G.

Combined error, relative degree m (3 velocity, 4 position)::

    s = e^(m-1) + lambda_{m-2} e^(m-2) + ... + lambda_0 e
    psi = F - y_d^(m) + lambda_{m-2} e^(m-1) + ... + lambda_0 e'

with lambda the Butterworth coefficients of order m-1 at f_r (Table I).
"""

from __future__ import annotations

import math

import numpy as np

from .layout import (
    C_BASE,
    C_BUMPLESS,
    C_EST,
    C_LAM0,
    C_LAW,
    C_LAYER_GAIN,
    C_N,
    C_NOISE_THETA,
    C_OMEGA_MAX,
    C_ORDER,
    C_P_BOUND,
    C_PDOMAIN,
    C_REF_ACCEL,
    C_SEED,
    C_SIGMA,
    C_SMOOTH,
    C_ULIM,
    DIV_NONE,
    DIV_NONFINITE,
    DIV_OMEGA,
    DIV_PRESSURE,
    EST_ANALOG,
    EST_ESO,
    EST_STATE,
    FB_D_OBS,
    FB_E_OBS,
    FB_PHI_EST,
    FB_PHI_OBS,
    FB_PHI_REF,
    FB_VEC,
    FB_VEC2,
    FBV_C_EST,
    FBV_C_REF,
    FBV_D_EST,
    FBV_D_REF,
    FBV_E_EST,
    FBV_E_REF,
    I_AM,
    I_E,
    I_E_R,
    I_E_TRUE,
    I_FRIC_ON,
    I_G,
    I_PSI,
    I_QUIET,
    I_R,
    I_RM,
    I_S,
    I_SAT,
    I_T,
    I_TF,
    I_UAPP,
    I_UBASE,
    I_UCMD,
    I_URES,
    I_V,
    I_W,
    I_WIN,
    I_XM,
    I_YD,
    I_YE,
    LAW_LIN_SONTAG,
    MAX_ORDER,
    N_CTRL,
    N_FB,
    N_PLANT,
    N_REF,
    QUIET_GUARD,
    QUIET_STARTUP,
    WIN_DISTURBANCE,
    WIN_STARTUP,
    WIN_TRACKING,
    X_OMEGA,
    X_PL,
    X_THETA,
    Z_EST,
    Z_NOISE,
    Z_OBS,
    Z_REF,
    Z_SHAPE,
)
from .params import P_DF, P_PS
from .physics import (
    LC_PS,
    active_amplitude,
    friction_torque,
    gaussian,
    jit,
    jit_noalloc,
    lane_rhs,
    lie_derivatives,
    relief,
)
from .signals import reference_value

NOISE_TAU = 0.02  # [s] time constant of the adaptive boundary layer's noise estimate (docs/MODEL.md, "Laws")


@jit
def smooth_sign(s, smoothing):
    """sign(s), or s / sqrt(s^2 + w^2) with the width w = ``smoothing`` > 0 (the boundary layer)."""
    if smoothing > 0.0:
        return s / math.sqrt(s * s + smoothing * smoothing)
    if s > 0.0:
        return 1.0
    if s < 0.0:
        return -1.0
    return 0.0


@jit
def switching_gain(s, n, sigma, scale):
    """|s/sigma|^(n-1) * scale / sigma >= 0 without overflow in the intermediate power (0 at s = 0).

    |s/sigma|^(n-1) is formed by repeated multiplication (cheap, and correctly scaled whenever it is a normal
    float), falling back to log space when it over- or underflows.
    """
    if s == 0.0:
        return 0.0
    x = abs(s) / sigma
    ni = int(n)
    p = _int_power(x, ni - 1) if ni == n else 0.0  # n is an even integer (check_n); 0.0: log space
    if 1e-290 < p < math.inf:
        # p * (scale/sigma) is correctly rounded and overflows only where the result itself does
        return p * (scale / sigma)
    # |s/sigma|^(n-1) itself over- or underflows: log space keeps the product
    return math.exp((n - 1.0) * math.log(x) + math.log(scale / sigma))


@jit
def sontag(psi, G, s, n, sigma, smoothing):
    """Sontag current [mA] for s' = psi + G u and V = (s/sigma)^n / n.

    Args:
        psi: drift of s [unit of s / s].
        G: input gain of s [unit of s / s per mA].
        s: combined error.
        n: even power factor >= 2.
        sigma: CLF scale (> 0), in the unit of s.
        smoothing: width w >= 0 of the smooth sign; 0 = plain sign(s).
    """
    if G == 0.0 or not math.isfinite(G):
        return 0.0
    sg = smooth_sign(s, smoothing)
    if sg == 0.0 and smoothing == 0.0:
        return 0.0  # s = 0, b = 0: Sontag's formula gives u = 0
    ratio = psi / G
    aG = abs(G)
    beta = switching_gain(s, n, sigma, aG)
    gsign = 1.0 if G > 0.0 else -1.0
    a = abs(ratio)
    big = a if a > beta else beta
    if 1e-150 < big < 1e150:  # the squares neither over- nor underflow: sqrt is cheaper than libm's hypot
        mag = math.sqrt(ratio * ratio + beta * beta)
    else:
        mag = math.hypot(ratio, beta)
    return -ratio - sg * gsign * mag


@jit
def lin_sontag(psi, G, s, n, sigma, smoothing, ulim):
    r"""Lin-Sontag current [mA], |u| <= ``ulim``, for s' = psi + G u and V = (s/sigma)^n / n.

    Lin & Sontag (1991) for the unit ball, with v = u / U (U = ``ulim``) and V' = a + b_v v::

        v = -(a + sqrt(a^2 + b_v^4)) b_v / (b_v^2 (1 + sqrt(1 + b_v^2))),   b_v = U b.

    With a = (s/sigma)^(n-1) psi / sigma and b_v = (s/sigma)^(n-1) U G / sigma sharing (s/sigma)^(n-1)
    (docs/MODEL.md, "Laws")::

        u = -(psi/G + sg sign(G) hypot(psi/G, U beta_U)) / (1 + |sg| sqrt(1 + beta_U^2)),
        beta_U = |s/sigma|^(n-1) U |G| / sigma,

    sg = sign(s) (|sg| = 1: the formula itself) or the smooth sign of width w. Wherever |psi| < U |G| (where
    V' < 0 is possible with |u| <= U) the command is within the bound and V' < 0 for every s != 0, the
    smoothed law included; at s = 0 the smoothed law is the equivalent control -psi/G. Elsewhere the
    formula asks for more than U and the command is clipped to U in its own direction, which minimises V'.
    Evaluated on scaled quantities (by max(|psi/(G U)|, beta_U, 1)), so nothing overflows; n enters only
    through beta_U.

    Args:
        psi, G, s, n, sigma, smoothing: as in :func:`sontag`.
        ulim: the bound U [mA] (finite, > 0).
    """
    if G == 0.0 or not math.isfinite(G):
        return 0.0
    sg = smooth_sign(s, smoothing)
    if sg == 0.0 and smoothing == 0.0:
        return 0.0  # b = 0
    gsign = 1.0 if G > 0.0 else -1.0
    rho = psi / (G * ulim)  # the equivalent control over the bound
    sgg = sg * gsign
    if not math.isfinite(rho):  # |psi/G| far beyond the bound: the limit of the formula
        if rho != rho:
            return rho
        return -ulim * (1.0 if rho > 0.0 else -1.0) if sgg * rho > 0.0 or abs(sg) < 1.0 else 0.0
    bu = switching_gain(s, n, sigma, ulim * abs(G))
    big = max(abs(rho), bu, 1.0)
    rs = rho / big
    bs = bu / big
    ib = 1.0 / big
    hyp = math.hypot(rs, bs)
    if sgg * rs < 0.0:
        # rs + sgg hyp cancels where |rho| >> beta_U (all digits lost at |rho| ~ 1e8 beta_U): rationalised,
        # rs + sgg hyp = sign(sgg) (sg^2 bs^2 - (1 - sg^2) rs^2) / (|sgg| hyp + |rs|), 1 - sg^2 = w^2/(s^2 + w^2)
        c = 0.0
        if smoothing > 0.0:
            r = s / smoothing
            c = 1.0 / (1.0 + r * r)
        num = (sg * sg * bs * bs - c * rs * rs) / (abs(sgg) * hyp + abs(rs))
        if sgg < 0.0:
            num = -num
    else:
        num = rs + sgg * hyp
    den = ib + abs(sg) * math.hypot(ib, bs)
    v = -num / den
    if v > 1.0:
        v = 1.0
    elif v < -1.0:
        v = -1.0
    return ulim * v


@jit
def _int_power(x, k):
    """x^k for an integer k >= 0 by repeated multiplication (k = n - 1 is small in practice).

    Several times cheaper than exp/log or pow; the result is within k ulp of x^k, and inf/0 only
    where x^k over-/underflows.
    """
    p = 1.0
    for _ in range(k):
        p *= x
    return p


@jit
def clf_value(s, n, sigma):
    """V = (s/sigma)^n / n."""
    ni = int(n)
    if ni == n and 0 < ni <= 16:  # n is an even integer in practice: multiplication, not pow()
        return _int_power(s / sigma, ni) / n
    return (s / sigma) ** n / n


@jit_noalloc
def controller_update(z, k, h, plant_p, model_p, ctrl, ref, events, filt, u_res, info, work):
    """The controller's work at t_k = k h; returns the applied current [mA].

    Measure (with noise), form the estimated output derivatives and the
    reference-model derivatives, compute the Sontag current, add the residual,
    apply the current limit, and advance the discrete filters (state z[4:]).
    The plant part z[:4] is left for the caller to integrate.

    It is :func:`controller_sense`, :func:`controller_apply` and
    :func:`advance_filters` in turn; only the middle one depends on ``u_res``,
    so a caller that already sensed sample k (the env's look-ahead) reuses that.

    Args:
        z: loop state (N_LOOP,), filter part updated in place.
        k: control step index.
        h: control period [s].
        plant_p: true plant parameters (PlantParams.as_array()).
        model_p: the controller's model parameters (mismatch when != plant_p).
        ctrl: controller row (layout C_*).
        ref: reference spec row (layout R_*).
        events: friction events (E, 3).
        filt: (N_FB, 4, 4) filter block (layout FB_*): Phi, c, E and D of the reference model
            and the estimator, zero-padded (:func:`ehss_gym.core.sim.filter_block`).
        u_res: residual current [mA] added to ctrl[C_BASE] times the Sontag current.
        info: output (N_INFO,), what the law saw and did at t_k.
        work: scratch (8, 4).
    """
    u_base = controller_sense(z, k, h, plant_p, model_p, ctrl, ref, events, filt, info, work)
    u_app = controller_apply(info, ctrl, u_base, u_res)
    advance_filters(z, h, ctrl, filt, info, work)
    return u_app


@jit_noalloc
def controller_sense(z, k, h, plant_p, model_p, ctrl, ref, events, filt, info, work):
    """Everything the controller computes at t_k that does not depend on the residual; returns u_base [mA].

    Fills ``info`` except I_URES, I_UCMD, I_UAPP, I_SAT (see :func:`controller_apply`). ``z`` is only read,
    except at k = 0 with a bumpless start, where the reference model's rows are set to the measured output
    and the estimated derivatives. Arguments as in :func:`controller_update`.
    """
    t = k * h
    m = int(ctrl[C_ORDER])
    n = ctrl[C_N]
    sigma = ctrl[C_SIGMA]
    seed = int(ctrl[C_SEED])
    xm = work[5]
    hd = work[6]
    for i in range(N_PLANT):
        sd = ctrl[C_NOISE_THETA + i]
        xm[i] = z[i] + (sd * gaussian(seed, k, i) if sd > 0.0 else 0.0)
    y_meas = xm[X_THETA] if m == 4 else xm[X_OMEGA]
    r = reference_value(t, ref)
    x3m = xm[X_PL]
    pmax = ctrl[C_PDOMAIN] * model_p[P_PS]  # the model's domain (docs/MODEL.md, "The model's pressure domain")
    if x3m > pmax:
        xm[X_PL] = pmax
    elif x3m < -pmax:
        xm[X_PL] = -pmax
    F, G = lie_derivatives(xm, model_p, m, hd)
    xm[X_PL] = x3m
    info[I_AM] = hd[2] if m == 4 else hd[1]  # the model's acceleration of the measured state
    estimate_derivatives(z, m, int(ctrl[C_EST]), filt, xm, hd, y_meas, info)
    bumpless = k == 0 and ctrl[C_BUMPLESS] != 0.0
    rm = r
    if ctrl[C_REF_ACCEL] > 0.0:
        rm = shape_reference(z, k, h, r, ctrl[C_REF_ACCEL], y_meas if bumpless else r)
    info[I_RM] = rm
    if bumpless:
        d = filt[FB_VEC2, FBV_D_REF]
        for i in range(m):  # outputs z_i = w_i + D_i v of the reference model = the estimator's
            z[Z_REF + i] = info[I_YE + i] - d[i] * rm
    # Reference model: y_d^(0..m-1) at the sample and y_d^(m) from its equation with the same input.
    ydm = filter_outputs(z, Z_REF, m, filt[FB_VEC, FBV_C_REF], filt[FB_VEC2, FBV_D_REF], rm, info, I_YD)
    info[I_YD + m] = ydm
    # Errors and the combined error; e itself uses the measured output.
    for i in range(m):
        info[I_E + i] = info[I_YE + i] - info[I_YD + i]
    y_true = z[X_THETA] if m == 4 else z[X_OMEGA]
    info[I_E_TRUE] = y_true - info[I_YD]
    info[I_E_R] = y_true - r
    s = info[I_E + m - 1]
    psi_lin = 0.0
    for i in range(m - 1):
        lam = ctrl[C_LAM0 + i]
        s += lam * info[I_E + i]
        psi_lin += lam * info[I_E + i + 1]
    psi = F - ydm + psi_lin
    w = ctrl[C_SMOOTH]
    gain = ctrl[C_LAYER_GAIN]
    if gain > 0.0:  # adaptive layer: the noise std of s from the running mean square of its steps
        wn = gain * math.sqrt(0.5 * z[Z_NOISE + 1])
        if wn > w:
            w = wn
    info[I_W] = w
    if ctrl[C_LAW] == LAW_LIN_SONTAG:
        u_base = lin_sontag(psi, G, s, n, sigma, w, ctrl[C_ULIM])
    else:
        u_base = sontag(psi, G, s, n, sigma, w)
    tf = friction_torque(t, z[X_OMEGA], events, plant_p[P_DF])
    info[I_T] = t
    for i in range(N_PLANT):
        info[I_XM + i] = xm[i]
    info[I_R] = r
    info[I_S] = s
    info[I_V] = clf_value(s, n, sigma)
    info[I_PSI] = psi
    info[I_G] = G
    info[I_UBASE] = u_base
    info[I_TF] = tf
    on = 0.0
    quiet = 1.0 if t >= QUIET_STARTUP else 0.0
    win = WIN_TRACKING if t >= QUIET_STARTUP else WIN_STARTUP
    for i in range(events.shape[0]):
        if events[i, 1] <= t < events[i, 2] + QUIET_GUARD:
            if win == WIN_TRACKING:  # an event's window counts whatever its amplitude (layout WIN_*)
                win = WIN_DISTURBANCE
            if events[i, 0] != 0.0:
                quiet = 0.0
                if t < events[i, 2]:
                    on = 1.0
    info[I_FRIC_ON] = on
    info[I_QUIET] = quiet
    info[I_WIN] = win
    return u_base


@jit
def estimate_derivatives(z, m, est, filt, xm, hd, y_meas, info):
    """info[I_YE + i], i < m: the measured output and the estimated y', ..., y^(m-1) (docs/MODEL.md, "Estimators").

    - SVF ("foh", "zoh", "analog"): the state-variable filter's outputs, its top derivative from its equation.
    - "state": the model's Lie derivatives of the measured state, ``hd`` (y' = L_f h(x_meas), ...).
    - "eso": the observer's velocity w_hat and acceleration a_m + d_hat (the model's acceleration of the
      measured state plus the estimated disturbance); the top derivative is the state's (L_f^(m-1) h).
    """
    if est == EST_STATE:
        for i in range(1, m):
            info[I_YE + i] = hd[i]
    elif est == EST_ESO:
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
    else:
        info[I_YE + m - 1] = filter_outputs(z, Z_EST, m - 1, filt[FB_VEC, FBV_C_EST], filt[FB_VEC2, FBV_D_EST],
                                            y_meas, info, I_YE)
    info[I_YE] = y_meas


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


@jit
def filter_outputs(z, off, order, c, d, v, out, o):
    """A digital filter's outputs at the sample: out[o + i] = z_i = w_i + d_i v (i < order); returns z^(order).

    ``z[off:off+order]`` is the filter state w (layout FB_*: D = 0 for "zoh" and "analog", where w is the
    state itself), v the input at the sample; the top derivative comes from the filter's own equation,
    z^(order) = c_0 v - sum_i c_i z_i, with the same v (NOTES item 12).
    """
    top = c[0] * v
    for i in range(order):
        zi = z[off + i] + d[i] * v
        out[o + i] = zi
        top -= c[i] * zi
    return top


@jit_noalloc
def controller_apply(info, ctrl, u_base, u_res):
    """Add the residual u_res [mA] to ctrl[C_BASE] * u_base [mA], apply the current limit; returns u_app [mA].

    Writes I_URES, I_UCMD, I_UAPP and I_SAT of ``info``.
    """
    u_cmd = ctrl[C_BASE] * u_base + u_res
    ulim = ctrl[C_ULIM]
    sat = 0.0
    u_app = u_cmd
    if u_cmd > ulim:
        u_app = ulim
        sat = 1.0
    elif u_cmd < -ulim:
        u_app = -ulim
        sat = 1.0
    info[I_URES] = u_res
    info[I_UCMD] = u_cmd
    info[I_UAPP] = u_app
    info[I_SAT] = sat
    return u_app


@jit_noalloc
def advance_filters(z, h, ctrl, filt, info, work):
    """Advance the controller's memory (z[4:]) over the period h [s]: the digital filters w <- Phi w + E v.

    The inputs v are the ones :func:`controller_sense` recorded in ``info``: r (I_R) for the reference model,
    the measured output (I_YE) for the SVF, the model acceleration and the measured velocity (I_AM, I_XM + 1)
    for the observer. With the "analog" scheme the plant's integrator advances the continuous filters. With
    an adaptive boundary layer the running mean square of the steps of s is updated (time constant
    NOISE_TAU).
    """
    if ctrl[C_LAYER_GAIN] > 0.0:
        s = info[I_S]
        if info[I_T] > 0.0:
            ds = s - z[Z_NOISE]
            a = h / NOISE_TAU if h < NOISE_TAU else 1.0
            z[Z_NOISE + 1] += a * (ds * ds - z[Z_NOISE + 1])
        z[Z_NOISE] = s
    est = ctrl[C_EST]
    if est == EST_ANALOG:
        return
    m = int(ctrl[C_ORDER])
    hd = work[6]
    advance_filter(z, Z_REF, m, filt[FB_PHI_REF], filt[FB_VEC, FBV_E_REF], info[I_RM], hd)
    if est == EST_ESO:
        am = info[I_AM]
        wm = info[I_XM + X_OMEGA]
        phi = filt[FB_PHI_OBS]
        e = filt[FB_E_OBS]
        w0 = phi[0, 0] * z[Z_OBS] + phi[0, 1] * z[Z_OBS + 1] + e[0, 0] * am + e[0, 1] * wm
        w1 = phi[1, 0] * z[Z_OBS] + phi[1, 1] * z[Z_OBS + 1] + e[1, 0] * am + e[1, 1] * wm
        z[Z_OBS] = w0
        z[Z_OBS + 1] = w1
    elif est != EST_STATE:
        advance_filter(z, Z_EST, m - 1, filt[FB_PHI_EST], filt[FB_VEC, FBV_E_EST], info[I_YE], hd)


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


@jit
def check_state(z, ctrl, plant_p):
    """DIV_* code of a loop state: non-finite, or outside the velocity/pressure bounds."""
    for i in range(z.shape[0]):
        if not math.isfinite(z[i]):
            return DIV_NONFINITE
    if abs(z[X_OMEGA]) > ctrl[C_OMEGA_MAX]:
        return DIV_OMEGA
    if abs(z[X_PL]) > ctrl[C_P_BOUND] * plant_p[P_PS]:
        return DIV_PRESSURE
    return DIV_NONE


@jit
def _lane_filter_rhs(X, ts, ctrl, ref, filt, ynoise, D, B):
    """D[4:, b] = the continuous reference model's and estimator's derivatives for the "analog" lanes.

    The reference model is driven by r(ts), the estimator by the plant output in X plus the sensor noise
    of the last sample (held: a sampled sensor). Other lanes get zeros (their filters are digital).
    """
    for b in range(B):
        for i in range(N_PLANT, D.shape[0]):
            D[i, b] = 0.0
        if ctrl[b, C_EST] != EST_ANALOG:
            continue
        m = int(ctrl[b, C_ORDER])
        cr = filt[b, FB_VEC, FBV_C_REF]
        acc = cr[0] * reference_value(ts, ref[b])
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
    """Advance B loops over [t0, t0+h] with their currents held (ZOH): classic RK4, ``substeps`` equal steps.

    The plant rows X[:4] of every lane are integrated (the arithmetic of :func:`ehss_gym.core.physics.
    integrate_plant`, bit for bit); with ``analog`` also the filter rows X[4:] of the lanes whose scheme is
    "analog": the reference model (input r(t)) and the estimator (input y(t) + the held noise) in the same
    RK4 stages, so they see the plant's intra-period motion as a continuous filter would. Friction events
    switch on the substep grid (the amplitude at each substep's midpoint, held over it).

    Args:
        X: loop states (N_LOOP, B) (rows as the loop state z; only 4 rows are read without ``analog``),
            updated in place.
        U: held currents (B,) [mA].
        t0: start time [s]; h: control period [s]; substeps: RK4 steps per period.
        c: lane constants (N_LANE_CONST, B).
        events: friction events (B, E, 3).
        work: scratch (6, N_LOOP, B).
        analog: integrate the analog lanes' filters too (some lane has the "analog" scheme).
        ctrl, ref, filt: controller rows, reference specs and filter blocks (B, ...); read with ``analog``.
        ynoise: the sensor noise on the output at the last sample (B,) [output unit]; read with ``analog``.
    """
    B = X.shape[1]
    n = X.shape[0] if analog else N_PLANT
    dt = h / substeps
    k1, k2, k3, k4, xt = work[0], work[1], work[2], work[3], work[4]  # the RK4 stages and the stage state
    amp = work[5, 0]
    for j in range(substeps):
        ts = t0 + j * dt
        for b in range(B):
            amp[b] = active_amplitude(t0 + (j + 0.5) * dt, events[b])
        for xs, kk, tstage, half in ((X, k1, ts, 0.5), (xt, k2, ts + 0.5 * dt, 0.5), (xt, k3, ts + 0.5 * dt, 1.0)):
            lane_rhs(xs, amp, U, c, kk, B)
            if analog:
                _lane_filter_rhs(xs, tstage, ctrl, ref, filt, ynoise, kk, B)
            for i in range(n):
                for b in range(B):
                    xt[i, b] = X[i, b] + half * dt * kk[i, b]
        lane_rhs(xt, amp, U, c, k4, B)
        if analog:
            _lane_filter_rhs(xt, ts + dt, ctrl, ref, filt, ynoise, k4, B)
        for i in range(n):
            for b in range(B):
                X[i, b] += dt / 6.0 * (k1[i, b] + 2.0 * k2[i, b] + 2.0 * k3[i, b] + k4[i, b])
        for b in range(B):
            X[X_PL, b] = relief(X[X_PL, b], c[LC_PS, b])


def plant_only_arrays(B: int):
    """(ctrl, ref, filt, ynoise) placeholders for :func:`integrate_lanes` without analog filters (never read)."""
    return np.zeros((B, N_CTRL)), np.zeros((B, N_REF)), np.zeros((B, N_FB, MAX_ORDER, MAX_ORDER)), np.zeros(B)
