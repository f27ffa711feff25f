"""The digital controller's work at each sample: measure, estimate, the reference model, the law's current.

One control period of the controller is :func:`controller_sense` (everything that does not depend on the residual:
the sensors with their noise and the model's Lie derivatives at the measured state (:mod:`ehss_gym.core.physics`), the
reference (:mod:`ehss_gym.core.references`), the estimated output derivatives (:mod:`ehss_gym.core.estimators`), the
reference shaper (here) and the reference model, the combined error s, its drift psi and input gain G, the law's current
(:mod:`ehss_gym.core.laws`)),
:func:`controller_apply` (the residual added, the current limit) and :func:`advance_filters` (the controller's memory
over the period); :func:`controller_update` runs the three. The controller knows its model of the plant, not the plant
itself nor the friction events; the loop around it is :mod:`ehss_gym.core.loop`.
"""

from __future__ import annotations

import math

import numpy as np

from .compensators import law_errors, valve_inverse
from .estimators import advance_filter, advance_filters, estimate_derivatives, filter_outputs
from .jit import jit, jit_inline, jit_noalloc
from .laws import base_current, clf_value, decrease_clip
from .layout import (
    FB_PHI_REF,
    FB_VEC,
    FB_VEC2,
    FBV_C_REF,
    FBV_D_REF,
    FBV_E_REF,
    I_AM,
    I_DHAT,
    I_E,
    I_E_R,
    I_E_TRUE,
    I_G,
    I_PSI,
    I_R,
    I_RM,
    I_S,
    I_SAT,
    I_SHIFT,
    I_T,
    I_UAPP,
    I_UBASE,
    I_UCMD,
    I_UDOB,
    I_URES,
    I_V,
    I_W,
    I_XM,
    I_YD,
    I_YE,
    N_LOOP,
    N_PLANT,
    X_AV,
    X_OMEGA,
    X_PL,
    X_THETA,
    Z_DOB,
    Z_NOISE,
    Z_REF,
    Z_SHAPE,
    Z_SHIFT,
)
from .params import P_PS
from .physics import LC_MODEL, LC_PMAX, gaussian, lie_terms, noise_uniforms, normal_from
from .references import reference_value
from .settings import (
    C_ANALOG,
    C_BASE,
    C_BUMPLESS,
    C_DOB_GAIN,
    C_EST,
    C_LAM0,
    C_LAW,
    C_LAYER_GAIN,
    C_LYAP_KAPPA,
    C_N,
    C_NOISE_THETA,
    C_ORDER,
    C_PDOMAIN,
    C_REF_ACCEL,
    C_SEED,
    C_SHIFT,
    C_SHIFT_ON,
    C_SIGMA,
    C_SMOOTH,
    C_ULIM,
)
from .unmodelled_kernels import sense_unmodelled
from .vecmath import NORMAL_REL, normal_block

NOISE_TAU = 0.02  # [s] time constant of the adaptive boundary layer's noise estimate (docs/MODEL.md, "Laws")


@jit_noalloc
def controller_update(z, k, h, model_p, ctrl, ref, filt, u_res, info, work):
    """The controller's work at t_k = k h; returns the applied current [mA].

    Measure (with noise), form the estimated output derivatives and the
    reference-model derivatives, advance the digital filters (state z[4:]),
    compute the law's current, add the residual and apply the current limit.
    The plant part z[:4] is left for the caller to integrate.

    It is :func:`controller_sense` and :func:`controller_apply` in turn; only the
    second depends on ``u_res``, so a caller that already sensed sample k (the
    env's look-ahead) reuses the first.

    Args:
        z: loop state (N_LOOP,), filter part updated in place.
        k: control step index.
        h: control period [s].
        model_p: the controller's model of the plant's parameters (PlantParams.as_array(); the controller knows
            neither the true plant nor the friction events).
        ctrl: controller row (:mod:`ehss_gym.core.settings`, C_*).
        ref: reference spec row (layout R_*).
        filt: (N_FB, 4, 4) filter block (layout FB_*): Phi, c, E and D of the reference model
            and the estimator, zero-padded (:func:`ehss_gym.core.filters.filter_block`).
        u_res: residual current [mA] added to ctrl[C_BASE] times the law's current.
        info: output (N_INFO,), what the law saw and did at t_k.
        work: scratch (8, 4).
    """
    u_base = controller_sense(z, k, h, model_p, ctrl, ref, filt, info, work)
    return controller_apply(z, info, ctrl, u_base, u_res)


@jit_noalloc
def controller_sense(z, k, h, model_p, ctrl, ref, filt, info, work):
    """Everything the controller computes at t_k that does not depend on the residual; returns u_base [mA].

    Fills ``info`` except I_URES, I_UCMD, I_UAPP, I_SAT (see :func:`controller_apply`) and I_TF (the plant's, the
    loop records it), and advances the controller's memory (z[4:]) over the period: the reference shaper, the
    digital filters w <- Phi w + E v with the inputs v of this sample (:func:`ehss_gym.core.estimators.advance_filters`;
    with an analog estimator the plant's integrator advances the continuous filters instead), with an adaptive
    boundary layer the running mean square of the steps of s (time constant NOISE_TAU) and, with the disturbance
    observer on, its estimate d_hat from this sample's s (:func:`dob_current`; its current is part of u_base). At
    k = 0 with a bumpless start the reference model's rows are first set to the measured output and the estimated
    derivatives. The plant rows z[:4] are only read. Arguments as in :func:`controller_update`.
    """
    xm = work[5]
    sense_plant(z, k, ctrl, xm)
    f2, h2, F, G = model_terms(xm[X_OMEGA], xm[X_PL], xm[X_AV], model_p, 0, ctrl[C_PDOMAIN] * model_p[P_PS])
    output_derivatives(xm[X_THETA], xm[X_OMEGA], f2, h2, ctrl[C_ORDER] == 4.0, work[6])
    return controller_law(z, k, h, F, G, f2, ctrl, ref, filt, info, work)


# Rows of the controller's lane-stage scratch (N_LOOP, B) (``lwork[6]`` of the loop): the measured states, the model
# there (F, G, f2, h2: :func:`model_terms`), the noise's uniform variates (4 channels each), which lanes sense, the
# noise samples' estimates (:func:`ehss_gym.core.vecmath.normal_block`), the readings left to libm, the noisy lanes'
# indices (int64 through a view), scratch, and the list of a channel's readings left to libm (int64 through a view).
# The noise's rows hold the noisy lanes only, packed: entry j is lane idx[j] (:func:`noisy_lanes`).
CW_XM, CW_MO, CW_U1, CW_U2, CW_TODO, CW_NZ, CW_LIBM, CW_IDX, CW_W, CW_LEFT = 0, 4, 8, 12, 16, 17, 21, 25, 26, 28
# Fewer noisy lanes than this in a block are sensed a lane at a time with libm (the same bits): the block's noise
# stages cost a dozen calls per period, more than libm's draws of a lane or two (measured on the single env).
NOISE_BLOCK_MIN = 4


@jit
def model_constants(model, ctrl, c):
    """Fill the controller's rows of the lane constants ``c`` (N_LANE_CONST, B): its model's parameters (LC_MODEL +
    P_*) from the rows ``model`` (B, N_PARAM) and the bound of the model's pressure domain (LC_PMAX) [Pa]."""
    for b in range(model.shape[0]):
        for i in range(model.shape[1]):
            c[LC_MODEL + i, b] = model[b, i]
        c[LC_PMAX, b] = ctrl[b, C_PDOMAIN] * model[b, P_PS]


@jit_inline
def sense_noise(z, k, ctrl, xm):
    """The sensors' readings at sample k: xm[i] = z[i] plus state i's noise (std ctrl[C_NOISE_THETA + i],
    :func:`ehss_gym.core.physics.gaussian`) [unit of state i], with libm's log and cos."""
    seed = int(ctrl[C_SEED])
    for i in range(N_PLANT):
        sd = ctrl[C_NOISE_THETA + i]
        xm[i] = z[i] + (sd * gaussian(seed, k, i) if sd > 0.0 else 0.0)


@jit_inline
def sense_plant(z, k, ctrl, xm):
    """Stage 1 of the controller, the sensors at sample k: the readings (:func:`sense_noise`), then the unmodelled
    encoder grid and sensor delay (:func:`ehss_gym.core.unmodelled_kernels.sense_unmodelled`, whose delay line is in
    z)."""
    sense_noise(z, k, ctrl, xm)
    sense_unmodelled(z, xm, k, ctrl)  # the encoder's grid and the sensor delay (off: nothing)


@jit_inline
def model_terms(x2, x3m, x4, p, o, pmax):
    """Stage 2 of the controller, the model ``p[o + P_*]`` at the measured state with its pressure x3m clipped to
    the model's domain +-``pmax`` [Pa] (docs/MODEL.md, "The model's pressure domain"): (f2, h2, F, G) of
    :func:`ehss_gym.core.physics.lie_terms`. Selects, no branch: the lane stage (:func:`sense_lanes`) vectorises it."""
    x3 = pmax if x3m > pmax else (-pmax if x3m < -pmax else x3m)
    return lie_terms(x2, x3, x4, p, o)


@jit_inline
def output_derivatives(x1, x2, f2, h2, position, hd):
    """The model's output y, y', ..., y^(m-1) at the measured state into ``hd``: (x1, x2, f2, h2) for the position
    output (m = 4), (x2, f2, h2) for the velocity (m = 3)."""
    hd[0] = x1 if position else x2
    hd[1] = x2 if position else f2
    hd[2] = f2 if position else h2
    hd[3] = h2 if position else 0.0


@jit_noalloc
def noisy_lanes(ctrl, todo, idx):
    """idx[:m] = the lanes flagged in ``todo`` that add noise to one of their sensors (a noise std > 0), in order;
    returns m. Only these draw variates: the others' readings are their states."""
    m = 0
    for b in range(ctrl.shape[0]):
        noisy = False
        for i in range(N_PLANT):
            noisy |= ctrl[b, C_NOISE_THETA + i] > 0.0
        if noisy and todo[b] != 0.0:
            idx[m] = b
            m += 1
    return m


@jit_noalloc
def noisy_readings(z, ctrl, idx, nz, xm, libm, i):
    """Channel ``i``'s reading of the noisy lanes b = idx[j]: xm[b] = z[b, i] + sd n (+ 0.0 without noise on this
    channel), with n the lane's Box-Muller sample, as :func:`sense_plant` computes it bit for bit. ``nz[j]`` is n's
    estimate within NORMAL_REL (:func:`ehss_gym.core.vecmath.normal_block`); the reading is the same double for every
    n within that bound (the roundings of sd n and of the sum are monotone in n, so both ends of the bracket giving
    one double settle it) wherever the noise is small against the state, as it is but near a zero of the state.
    Elsewhere ``libm[j]`` is set for :func:`sense_lanes` to take libm's sample. Selects, no branch: the loop
    vectorises. Returns how many readings are left to libm."""
    n_libm = 0
    for j in range(idx.shape[0]):
        b = idx[j]
        x = z[b, i]
        sd = ctrl[b, C_NOISE_THETA + i]
        n = nz[j]
        d = abs(n) * NORMAL_REL
        lo = x + sd * (n - d)
        hi = x + sd * (n + d)
        noisy = sd > 0.0
        left = noisy & (lo != hi)  # lo != hi: also a NaN anywhere (libm's then decides, as before)
        xm[b] = lo if noisy else x + 0.0
        libm[j] = 1.0 if left else 0.0
        n_libm += left
    return n_libm


@jit_noalloc
def sense_lanes(z, kv, ctrl, c, cw):
    """Stages 1 and 2 of the controller for the lanes of a block flagged in ``cw[CW_TODO]``, each a loop over the lanes
    (the same arithmetic as :func:`controller_sense` does for one lane, bit for bit): the readings without noise,
    then for the lanes that add noise (:func:`noisy_lanes`, packed) the noise's uniform variates (integer arithmetic,
    vectorised), their Box-Muller samples' estimates (:func:`ehss_gym.core.vecmath.normal_block`, vectorised) and
    the readings (:func:`noisy_readings`, with libm's log and cos for the few a bracket does not settle); the encoder
    grid and sensor delay per lane; then the model at every lane's measured state (vectorised; the model's rows of
    the lane constants ``c``, :func:`model_constants`). Lane b is at its own sample ``kv[b]``. Writes the rows CW_*
    of the scratch ``cw`` (N_LOOP, B)."""
    B = z.shape[0]
    XM = cw[CW_XM:CW_XM + 4]
    MO = cw[CW_MO:CW_MO + 4]
    todo = cw[CW_TODO]
    for b in range(B):
        if todo[b] != 0.0:
            for i in range(N_PLANT):
                XM[i, b] = z[b, i] + 0.0
    idx_all = cw[CW_IDX].view(np.int64)
    m = noisy_lanes(ctrl, todo, idx_all)
    if 0 < m < NOISE_BLOCK_MIN:
        for j in range(m):
            b = idx_all[j]
            sense_noise(z[b], kv[b], ctrl[b], XM[:, b])
    elif m > 0:
        idx = idx_all[:m]
        for i in range(N_PLANT):
            u1, u2, nz, libm = cw[CW_U1 + i, :m], cw[CW_U2 + i, :m], cw[CW_NZ + i, :m], cw[CW_LIBM + i, :m]
            for j in range(m):
                b = idx[j]
                u1[j], u2[j] = noise_uniforms(int(ctrl[b, C_SEED]), kv[b], i)
            normal_block(u1, u2, nz, cw[CW_W, :m], cw[CW_W + 1, :m])
            n_left = noisy_readings(z, ctrl, idx, nz, XM[i], libm, i)
            if n_left > 0:
                # the readings left to libm listed first, by a store per lane and no branch: which ones are left is as
                # random as the noise (on the load pressure about two in five), so a branch per lane was mispredicted
                left = cw[CW_LEFT].view(np.int64)
                q = 0
                for j in range(m):
                    left[q] = j
                    q += libm[j] != 0.0
                for r in range(n_left):
                    j = left[r]
                    b = idx[j]
                    XM[i, b] = z[b, i] + ctrl[b, C_NOISE_THETA + i] * normal_from(u1[j], u2[j])
    for b in range(B):
        if todo[b] != 0.0:
            sense_unmodelled(z[b], XM[:, b], kv[b], ctrl[b])  # the encoder's grid and the sensor delay (off: nothing)
    for b in range(B):
        f2, h2, F, G = model_terms(XM[X_OMEGA, b], XM[X_PL, b], XM[X_AV, b], c[:, b], LC_MODEL, c[LC_PMAX, b])
        MO[0, b] = F
        MO[1, b] = G
        MO[2, b] = f2
        MO[3, b] = h2


@jit_noalloc
def law_lanes(z, kv, h, ctrl, ref, filt, info, work, cw):
    """Stages 3 on of the controller for the lanes of a block flagged in ``cw[CW_TODO]``, after :func:`sense_lanes`:
    each lane's u_base [mA] into ``info[b, I_UBASE]`` and the rest of ``info[b]`` as :func:`controller_sense` writes
    it, bit for bit.

    The law's body (:func:`order_law`) is compiled once per relative degree m, with m a constant, so the compiler
    unrolls every loop over the output's derivatives: the velocity lanes run :func:`velocity_lanes`, the position
    lanes :func:`position_lanes` (a block of one task, as every env's, makes one of the two calls). Lane b's loop
    state is the last N_LOOP entries of ``z[b]`` (the look-ahead's copy sits beside its info in one row; the offset is
    read from the shape, not passed, so one compiled version serves both).
    """
    zoff = z.shape[1] - N_LOOP
    velocity = False
    position = False
    for b in range(z.shape[0]):
        if cw[CW_TODO, b] != 0.0:
            velocity |= ctrl[b, C_ORDER] == 3.0
            position |= ctrl[b, C_ORDER] == 4.0
    if velocity:
        velocity_lanes(z, kv, h, ctrl, ref, filt, info, work, cw, zoff)
    if position:
        position_lanes(z, kv, h, ctrl, ref, filt, info, work, cw, zoff)


@jit_inline
def order_lanes(z, kv, h, ctrl, ref, filt, info, work, cw, zoff, m):
    """:func:`law_lanes` for the flagged lanes of relative degree ``m``, a compile-time constant where
    :func:`velocity_lanes` and :func:`position_lanes` call it."""
    for b in range(z.shape[0]):
        if cw[CW_TODO, b] == 0.0 or ctrl[b, C_ORDER] != m:
            continue
        for i in range(N_PLANT):
            work[5, i] = cw[CW_XM + i, b]
        output_derivatives(cw[CW_XM, b], cw[CW_XM + 1, b], cw[CW_MO + 2, b], cw[CW_MO + 3, b], m == 4, work[6])
        order_law(z[b, zoff:], kv[b], h, cw[CW_MO, b], cw[CW_MO + 1, b], cw[CW_MO + 2, b], ctrl[b], ref[b], filt[b],
                  info[b], work, m)


@jit_noalloc
def velocity_lanes(z, kv, h, ctrl, ref, filt, info, work, cw, zoff):
    """:func:`order_lanes` compiled for the velocity output (m = 3)."""
    order_lanes(z, kv, h, ctrl, ref, filt, info, work, cw, zoff, 3)


@jit_noalloc
def position_lanes(z, kv, h, ctrl, ref, filt, info, work, cw, zoff):
    """:func:`order_lanes` compiled for the position output (m = 4)."""
    order_lanes(z, kv, h, ctrl, ref, filt, info, work, cw, zoff, 4)


@jit_noalloc
def controller_law(z, k, h, F, G, am, ctrl, ref, filt, info, work):
    """Stages 3 on of the controller at t_k, after the sensors and the model: the reference, the estimator, the
    reference shaper and model, s, psi, the controller's memory, the law; returns u_base [mA]. ``work[5]`` holds the
    measured state and ``work[6]`` the model's output derivatives there (``work[6]`` is scratch afterwards), F, G
    and a_m (= f2) the model's (:func:`model_terms`). Writes ``info`` as :func:`controller_sense` says.

    The lanes of a block run the same body compiled for their relative degree (:func:`law_lanes`)."""
    return order_law(z, k, h, F, G, am, ctrl, ref, filt, info, work, int(ctrl[C_ORDER]))


@jit_inline
def order_law(z, k, h, F, G, am, ctrl, ref, filt, info, work, m):
    """:func:`controller_law`'s body for the relative degree ``m`` (3 velocity, 4 position): a compile-time constant
    where :func:`order_lanes` calls it, so the compiler unrolls every loop over the output's derivatives (the same
    arithmetic in the same order, bit for bit what the loops bounded at run time give)."""
    t = k * h
    n = ctrl[C_N]
    sigma = ctrl[C_SIGMA]
    xm = work[5]
    hd = work[6]
    y_meas = xm[X_THETA] if m == 4 else xm[X_OMEGA]
    info[I_AM] = am
    # the reference, the estimated output derivatives, and the reference's shaped form that drives the model
    r = reference_value(t, ref)
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
    # Errors (against y_d, or y_d delayed by the reference delay: law_errors) and the combined error; e itself uses
    # the measured output.
    ydm = law_errors(z, k, m, ctrl, info)
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
    info[I_SHIFT] = 0.0
    if ctrl[C_SHIFT_ON] != 0.0:  # the law tracks y_d + Delta: its s and psi lose Delta's share
        shift, s_shift, psi_shift = reference_shift(z, m, ctrl, filt, hd)
        info[I_SHIFT] = shift
        s -= s_shift
        psi -= psi_shift
    w = ctrl[C_SMOOTH]
    gain = ctrl[C_LAYER_GAIN]
    if gain > 0.0:  # adaptive layer: the noise std of s from the running mean square of its steps
        wn = gain * math.sqrt(0.5 * z[Z_NOISE + 1])
        if wn > w:
            w = wn
    info[I_W] = w
    info[I_T] = t
    for i in range(N_PLANT):
        info[I_XM + i] = xm[i]
    info[I_R] = r
    info[I_S] = s
    info[I_PSI] = psi
    info[I_G] = G
    # the controller's memory over the period, from this sample's inputs (none depends on the residual)
    if gain > 0.0:
        if t > 0.0:
            ds = s - z[Z_NOISE]
            a = h / NOISE_TAU if h < NOISE_TAU else 1.0
            z[Z_NOISE + 1] += a * (ds * ds - z[Z_NOISE + 1])
        z[Z_NOISE] = s
    if ctrl[C_ANALOG] == 0.0:
        advance_filters(z, m, int(ctrl[C_EST]), filt, info, hd)
    if ctrl[C_SHIFT_ON] != 0.0:
        advance_filter(z, Z_SHIFT, m, filt[FB_PHI_REF], filt[FB_VEC, FBV_E_REF], ctrl[C_SHIFT], hd)
    # the law
    u_base = base_current(ctrl[C_LAW], psi, G, s, n, sigma, w, ctrl[C_ULIM])
    info[I_DHAT] = 0.0
    info[I_UDOB] = 0.0
    alpha = ctrl[C_DOB_GAIN]
    if alpha > 0.0:
        u_base += dob_current(z, k, h, alpha, s, G, ctrl[C_ULIM], info)
    info[I_V] = clf_value(s, n, sigma)
    info[I_UBASE] = u_base
    return u_base


@jit
def reference_shift(z, m, ctrl, filt, dd):
    r"""The law's reference shift at the sample: (Delta, its share of s, its share of psi).

    The shift delta = ``ctrl[C_SHIFT]`` [output unit] drives a copy of the reference model (the same digital filter,
    its state z[Z_SHIFT:Z_SHIFT+m]), whose outputs Delta, Delta', ..., Delta^(m) are therefore consistent derivatives
    of one smooth signal: by linearity the law tracks the reference model's response to r + delta, y_d + Delta, while
    y_d (I_YD, the errors I_E and the true error the metrics measure) stays the response to r. With the law's errors
    e_i - Delta^(i) the combined error and its drift become s - (Delta^(m-1) + sum_i lambda_i Delta^(i)) and
    psi - (Delta^(m) + sum_i lambda_i Delta^(i+1)); with delta = 0 from the start both shares are exactly 0. ``dd``
    (>= m) receives Delta^(i), i < m (scratch).
    """
    top = filter_outputs(z, Z_SHIFT, m, filt[FB_VEC, FBV_C_REF], filt[FB_VEC2, FBV_D_REF], ctrl[C_SHIFT], dd, 0)
    s_shift = dd[m - 1]
    psi_shift = top
    for i in range(m - 1):
        lam = ctrl[C_LAM0 + i]
        s_shift += lam * dd[i]
        psi_shift += lam * dd[i + 1]
    return dd[0], s_shift, psi_shift


@jit
def dob_current(z, k, h, alpha, s, G, ulim, info):
    """The disturbance observer at sample k: its estimate d_hat updated from this sample's s; returns its current [mA].

    The combined error obeys s' = psi + G u + d, d the lumped effect of what the model leaves out (friction,
    mismatch). The innovation (s_k - s_{k-1})/h - (psi_{k-1} + G_{k-1} u_app,k-1) measures d over the last period
    (the prediction was recorded by :func:`controller_apply`); a first-order filter of gain ``alpha`` = 1 -
    exp(-2 pi f_d h) [-] smooths it into d_hat [unit of s / s], and the current -d_hat/G [mA], clipped to +-``ulim``,
    cancels it (docs/MODEL.md, "Disturbance observer"). At k = 0 there is no last period: d_hat stays at its initial
    0. Writes I_DHAT and I_UDOB of ``info``.
    """
    if k > 0:
        innovation = (s - z[Z_DOB + 1]) / h - z[Z_DOB + 2]
        z[Z_DOB] += alpha * (innovation - z[Z_DOB])
    d_hat = z[Z_DOB]
    u = -d_hat / G if G != 0.0 else 0.0
    if u > ulim:
        u = ulim
    elif u < -ulim:
        u = -ulim
    info[I_DHAT] = d_hat
    info[I_UDOB] = u
    return u


@jit_inline
def controller_apply(z, info, ctrl, u_base, u_res):
    """Add the residual u_res [mA] to ctrl[C_BASE] * u_base [mA], pass the sum through the valve inverse (a loop
    setting, off by default: :func:`ehss_gym.core.compensators.valve_inverse`), apply the current limit; returns u_app
    [mA].

    Writes I_URES, I_UCMD, I_UAPP and I_SAT of ``info`` and, with the disturbance observer on, records in z what it
    compares the next sample with: this sample's s and its prediction psi + G u_app of s' (the applied current, so a
    clipped command does not wind the estimate up).
    """
    u_res = lyapunov_residual(info, ctrl[C_LYAP_KAPPA], ctrl[C_BASE] * u_base, u_res)
    u_cmd = valve_inverse(z, ctrl[C_BASE] * u_base + u_res, ctrl)  # the valve inverse (off: the sum itself)
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
    if ctrl[C_DOB_GAIN] > 0.0:
        z[Z_DOB + 1] = info[I_S]
        z[Z_DOB + 2] = info[I_PSI] + info[I_G] * u_app
    return u_app


@jit_inline
def lyapunov_residual(info, kappa, u0, u_res):
    r"""The residual [mA] of the Lyapunov-constrained mode: ``u_res`` clipped so that V' <= kappa * the law's decrease.

    Derivation, in the law's own terms (:mod:`ehss_gym.core.laws`). With s' = psi + G u and V = (s/sigma)^n / n,
    V' = a + b u with a = q psi / sigma, b = q G / sigma, q = (s/sigma)^(n-1). n is even, so q has the sign of s and
    |q| / sigma > 0 wherever s != 0; dividing by it,

        V' <= kappa D   <=>   a' + b' u <= kappa D',   a' = sign(s) psi,  b' = sign(s) G,  D' = a' + b' u_law,

    D = (|q| / sigma) D' the law's own decrease V' at its current u_law (the base current without the disturbance
    observer's). For the plain Sontag law D = -sqrt(a^2 + b^4), i.e. D' = -|G| hypot(psi/G, |q| |G| / sigma); the
    smoothed law's is |sgn_w(s)| times that and Lin-Sontag's its own, all read off u_law, so no power of s is formed
    and neither n nor sigma enters. Where D' < 0 (the law makes V decrease) the residual is the nearest to ``u_res``
    with a' + b' (u0 + r) <= kappa D' (:func:`ehss_gym.core.laws.decrease_clip`); since kappa < 1 and D' < 0, the
    law's current alone qualifies (r = 0 with the observer off): the clip never asks more than doing nothing. Elsewhere
    (s = 0, or a law that cannot make V decrease there) the residual is left as commanded. The current limit applied
    afterwards keeps the condition wherever some current within the limit meets it (a clip onto an interval keeps a
    point of a half-line in it when they meet). With the observer on, its current is part of u0 and counts against
    the same bound.

    Args:
        info: the sample's info (layout I_*): s, psi, G, the base current and the observer's part.
        kappa: the share of the law's decrease kept, in [0, 1); < 0 = off (``u_res`` returned as is).
        u0: the current the residual is added to [mA] (C_BASE times the base current).
        u_res: the commanded residual [mA].
    """
    if kappa < 0.0:
        return u_res
    s = info[I_S]
    if s == 0.0:
        return u_res
    sg = 1.0 if s > 0.0 else -1.0
    a = sg * info[I_PSI]
    b = sg * info[I_G]
    decrease = a + b * (info[I_UBASE] - info[I_UDOB])
    if not decrease < 0.0:
        return u_res
    return decrease_clip(a, b, u0, u_res, kappa * decrease)


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


@jit_inline
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


@jit_inline
def _sgn(x):
    return 1.0 if x > 0.0 else (-1.0 if x < 0.0 else 0.0)


__all__ = ["controller_update", "controller_sense", "controller_apply", "sense_plant", "sense_noise", "model_terms",
           "output_derivatives", "noisy_lanes", "noisy_readings", "sense_lanes", "law_lanes", "order_lanes",
           "velocity_lanes", "position_lanes", "controller_law", "order_law", "model_constants",
           "dob_current", "lyapunov_residual", "reference_shift", "shape_reference", "fhan", "NOISE_TAU", "CW_XM",
           "CW_MO", "CW_U1", "CW_U2", "CW_TODO", "CW_NZ", "CW_LIBM", "CW_IDX", "CW_W",
           "CW_LEFT"]
