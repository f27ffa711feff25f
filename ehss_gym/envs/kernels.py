"""The env's compiled step: B lanes advanced ``agent_period`` control periods in one call, reward and observation.

Every buffer index is named in :mod:`ehss_gym.envs.buffers` (F_*, IB_*, BB_*, S_*, W_*, LAY_*).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from ehss_gym.core.controller import CW_TODO, controller_apply, law_lanes, sense_lanes
from ehss_gym.core.jit import dispatch, jit, jit_inline, jit_noalloc
from ehss_gym.core.layout import (
    I_E,
    I_E_TRUE,
    I_SAT,
    I_UAPP,
    I_UBASE,
    M_DST_MAX,
    M_DST_STEPS,
    M_DST_SUM_ABS,
    M_LOST,
    M_SUM_U2,
    M_TRK_STEPS,
    M_TRK_SUM_ABS,
    M_TRK_SUM_E2,
    M_TV_U,
    N_INFO,
    N_LOOP,
    N_METRICS,
    N_PARAM,
    N_REF,
)
from ehss_gym.core.loop import copy_live, lanes_period
from ehss_gym.core.settings import N_CTRL
from ehss_gym.core.vecmath import symlog_block

from .actions import ACTIONS
from .buffers import (
    BB_ACT,
    BB_PRE,
    BB_RUN,
    F_ACT,
    F_APREV,
    F_MEM,
    F_RCLS,
    F_REW,
    F_RPHYS,
    F_STATS,
    F_URES,
    FLAG_LAST,
    FLAG_MEM,
    FLAG_SQUASH,
    H_ACC,
    H_CTRL,
    H_INFO,
    H_INFO_OK,
    H_MODEL,
    H_PEEK,
    H_PLANT,
    H_REF,
    H_Z,
    H_ZPREV,
    IB_GID,
    IB_K,
    IB_KJ,
    IB_NSTEP,
    LAY_FLAGS,
    LAY_SCALE,
    LAY_SRC,
    MEM_APREV2,
    MEM_EINT,
    N_MEM,
    N_PARTS,
    N_PEEK,
    N_RCLS,
    N_RPHYS,
    N_STATS,
    N_WEIGHTS,
    P_DMA,
    P_K,
    P_MA,
    P_MS,
    P_N,
    P_NCLS,
    P_NDST,
    P_NTRK,
    P_PK,
    P_TV,
    P_U2,
    R_B,
    R_DST_ABS,
    R_DST_MAX,
    R_K,
    R_TRK_ABS,
    R_TRK_E2,
    R_TV,
    R_W,
    S_DST_ABS,
    S_DST_MAX,
    S_DST_N,
    S_EMAX,
    S_N,
    S_SAT,
    S_SATF,
    S_SUM_E2,
    S_TRK_ABS,
    S_TRK_E2,
    S_TRK_N,
    S_TV0,
    S_U2,
    S_UMAX,
    S_UMIN,
    W_ACT_C1,
    W_ACT_C2,
    W_ACT_MODE,
    W_ACT_PERIOD,
    W_CLASS,
    W_DIV,
    W_EFFORT,
    W_INV_E2,
    W_INV_SCALE,
    W_MEM_CLIP,
    W_MEM_DECAY,
    W_MEM_GAIN,
    W_PHYS,
    W_RATE,
    W_SAT,
    W_TRACK,
    W_TV,
    W_TVU,
    block,
)
from .observation import OBS_BOUND


@jit_inline
def _obs_input(x, scale):
    """An observation entry's value before the squash: x / scale, a non-finite one replaced by +-OBS_BOUND (0 for
    NaN)."""
    v = x / scale
    if not math.isfinite(v):
        v = OBS_BOUND if v > 0.0 else (-OBS_BOUND if v < 0.0 else 0.0)
    return v


@jit_inline
def _obs_clip(v):
    """An observation entry clipped to +-OBS_BOUND."""
    return OBS_BOUND if v > OBS_BOUND else (-OBS_BOUND if v < -OBS_BOUND else v)


@jit_noalloc
def observe_lanes(obs, peek, last, F, lay, gid, scratch):
    """The observations of the lanes with ``gid`` 0: entry i of lane b is symlog(x / scale), clipped to
    +-OBS_BOUND, finite, where x (layout ``lay``, :mod:`ehss_gym.envs.observation`) is read from the look-ahead
    ``peek[b]`` (what the controller sees at the next sample) or, for entries flagged FLAG_LAST, from ``last[b]``
    (the last control period actually run, H_INFO_OK: applied current, residual), or for entries flagged FLAG_MEM
    from the lane's extras in ``F`` (the memory features, layout MEM_*, then the action of a mode but "current").

    One entry at a time over the lanes, so the squash runs on the whole block
    (:func:`ehss_gym.core.vecmath.symlog_block`, whose float32 result is libm's log1p's, bit for bit).
    ``scratch`` is a C-contiguous float64 array of at least 6 B entries."""
    B = obs.shape[0]
    s = scratch.reshape(-1)[:6 * B].reshape(6, B)  # rows of exactly B lanes (a chunk's scratch may be longer)
    v, y, w = s[0], s[1], s[2:6]
    for i in range(lay.shape[1]):
        j = int(lay[LAY_SRC, i])
        fl = int(lay[LAY_FLAGS, i])
        scale = lay[LAY_SCALE, i]
        for b in range(B):
            x = F[b, F_MEM + j] if fl & FLAG_MEM else (last[b, j] if fl & FLAG_LAST else peek[b, j])
            v[b] = _obs_input(x, scale)
        if fl & FLAG_SQUASH:
            symlog_block(v, y, w)
        else:
            for b in range(B):
                y[b] = v[b]
        for b in range(B):
            if gid[b] == 0:
                obs[b, i] = _obs_clip(y[b])


@jit_inline
def hot_blocks(H, B, s, n):
    """The hot blocks (buffers.H_*) of lanes s, ..., s + n - 1 of the flat buffer ``H`` of ``B`` lanes: the loop states,
    plant rows, model rows, controller rows, reference rows, info, last finite info, look-ahead, metrics accumulators
    and the loop states at the last sample, each a (n, width) view with contiguous lane rows."""
    return (block(H, B, H_Z, N_LOOP)[s:s + n], block(H, B, H_PLANT, N_PARAM)[s:s + n],
            block(H, B, H_MODEL, N_PARAM)[s:s + n], block(H, B, H_CTRL, N_CTRL)[s:s + n],
            block(H, B, H_REF, N_REF)[s:s + n], block(H, B, H_INFO, N_INFO)[s:s + n],
            block(H, B, H_INFO_OK, N_INFO)[s:s + n], block(H, B, H_PEEK, N_PEEK)[s:s + n],
            block(H, B, H_ACC, N_METRICS)[s:s + n], block(H, B, H_ZPREV, N_LOOP)[s:s + n])


@jit_noalloc
def peek_lanes(z, ctrl, ref, peek, u_res, BB, gid, kv, h, filt, c, work, cw):
    """Fill the look-ahead block ``peek`` of every lane that stepped in this call (``gid`` 0, IB_GID) with what its
    controller sees at its next sample kv[b], without advancing it.

    The controller's stages run on copies of the loop states kept in the blocks' last N_LOOP entries: the sensors and
    model over the lanes (:func:`ehss_gym.core.controller.sense_lanes`), the rest of the law over them
    (:func:`ehss_gym.core.controller.law_lanes`), the residual (:func:`ehss_gym.core.controller.controller_apply`);
    the arithmetic of :func:`ehss_gym.core.controller.controller_update` on each copy. BB_PRE is set: the lane's next
    control period (at this k, from this state) reuses all of it and only applies its residual (see
    :func:`ehss_gym.core.loop.lanes_period`), so look-ahead and step share one controller evaluation."""
    B = z.shape[0]
    zt = peek[:, N_INFO:]  # the copies, which the sensors' delay line moves on (the loop state stays)
    for b in range(B):
        member = gid[b] == 0
        cw[CW_TODO, b] = 1.0 if member else 0.0
        if member:
            copy_live(zt[b], z[b], ctrl[b], 0)  # the rows it can write or read; the others are never read
    sense_lanes(zt, kv, ctrl, c, cw)
    law_lanes(peek, kv, h, ctrl, ref, filt, peek, work, cw)  # a lane's info and state copy share its row
    for b in range(B):
        if gid[b] != 0:
            continue
        pk = peek[b, :N_INFO]
        controller_apply(peek[b, N_INFO:], pk, ctrl[b], pk[I_UBASE], u_res[b])
        BB[b, BB_PRE] = True


@jit_noalloc
def observe(h, F, H, IB, BB, filt, c, work, lwork, obs, lay):
    """Observations of the lanes flagged in BB[:, BB_ACT] at their current step, without advancing them: each chunk's
    flagged lanes through :func:`peek_lanes` and :func:`observe_lanes`, as a step ends (``c``, ``work``, ``lwork``:
    the chunks' scratch, as :func:`advance_chunks` takes them).

    Used at reset: the last-period block (applied current, residual) is zeroed, nothing was applied yet.
    """
    B_all = F.shape[0]
    chunk = c.shape[2]
    for j in range(c.shape[0]):
        s = j * chunk
        B = min(chunk, B_all - s)
        z, _, _, ctrl, ref, _, info_ok, peek, _, _ = hot_blocks(H, B_all, s, B)
        # the step's group row marks the flagged lanes, as a step's does (advance writes it afresh before using it)
        gid, kv = IB[IB_GID, s:s + B], IB[IB_K, s:s + B]
        for b in range(B):
            gid[b] = 0 if BB[s + b, BB_ACT] else -1
            if BB[s + b, BB_ACT]:
                for i in range(N_INFO):
                    info_ok[b, i] = 0.0
        peek_lanes(z, ctrl, ref, peek, F[s:s + B, F_URES], BB[s:s + B], gid, kv, h, filt[s:s + B], c[j],
                   work[j], lwork[j, 6])
        observe_lanes(obs[s:s + B], peek, info_ok, F[s:s + B], lay, gid, lwork[j, 0])


def reward_weights(weights: dict, error_scale: float, residual_scale: float, memory_tau: float | None = None,
                   agent_dt: float = 1.0) -> np.ndarray:
    """The ``wts`` vector :func:`agent_reward`, :func:`class_reward` and :func:`physical_reward` read (W_* slots),
    from the env's settings.

    Args:
        weights: the env's ``reward_weights`` (track, effort, rate, tv, tv_u, divergence, class, saturation,
            physical) [-].
        error_scale: the tracking error that costs 1 per step [output unit].
        residual_scale: the current of a unit action [mA].
        memory_tau: time constant of the memory's filtered error integral [s]; None = no memory features.
        agent_dt: the agent step [s] (the memory filter's step).
    """
    wts = np.zeros(N_WEIGHTS)
    for slot, key in ((W_TRACK, "track"), (W_EFFORT, "effort"), (W_RATE, "rate"), (W_TV, "tv"), (W_TVU, "tv_u"),
                      (W_DIV, "divergence"), (W_CLASS, "class"), (W_SAT, "saturation"), (W_PHYS, "physical")):
        wts[slot] = weights.get(key, 0.0)
    wts[W_INV_E2] = 1.0 / error_scale**2
    wts[W_INV_SCALE] = 1.0 / residual_scale
    if memory_tau is not None:  # x' = e - x/tau over the step, e held: exact decay and gain; |x| <= 10 error_scale tau
        decay = np.exp(-agent_dt / memory_tau)
        wts[W_MEM_DECAY] = decay
        wts[W_MEM_GAIN] = -memory_tau * np.expm1(-agent_dt / memory_tau)
        wts[W_MEM_CLIP] = MEM_CLIP * error_scale * memory_tau
    return wts


MEM_CLIP = 10.0  # anti-windup: the filtered integral is clipped to +-MEM_CLIP * error_scale * memory_tau


@jit
def agent_reward(a, a_prev, n, sum_e2, tv_added, diverged, wts):
    """The reward of one agent step (the env's docstring states it); a pure function of its arguments.

    Args:
        a, a_prev: the clipped action of this and of the previous step [-].
        n: control periods run in the step; sum_e2: sum of their squared errors [output unit^2].
        tv_added: the applied current's total variation over the step [mA].
        diverged: the loop diverged during the step (the tracking term is then dropped).
        wts: reward weights (layout W_*: track, effort, rate, tv, tv_u, divergence, 1/error_scale^2,
            1/residual_scale).
    """
    da = 0.5 * (a - a_prev)
    r = -wts[W_EFFORT] * a * a - wts[W_RATE] * da * da - wts[W_TV] * abs(da)
    if n > 0.0:
        r -= wts[W_TVU] * tv_added / n * wts[W_INV_SCALE]
    if diverged:
        r -= wts[W_DIV]
    elif n > 0.0:
        r += wts[W_TRACK] / (1.0 + sum_e2 / n * wts[W_INV_E2])
    return r


@jit
def snapshot_classes(st, acc):
    """Record in a lane's step statistics ``st`` (S_*) the accumulator's class sums as the step begins."""
    st[S_TV0] = acc[M_TV_U]
    st[S_TRK_E2] = acc[M_TRK_SUM_E2]
    st[S_TRK_ABS] = acc[M_TRK_SUM_ABS]
    st[S_DST_ABS] = acc[M_DST_SUM_ABS]
    st[S_DST_MAX] = acc[M_DST_MAX]
    st[S_U2] = acc[M_SUM_U2]
    st[S_TRK_N] = acc[M_TRK_STEPS]
    st[S_DST_N] = acc[M_DST_STEPS]


CLASS_EPS = 1e-2  # the class reward's offset, as a share of the base law's total of each part


@jit
def class_reward(st, acc, rc, j, diverged, wts):
    """The class reward of one agent step (step ``j`` of the episode, from 0): minus the step's change of the
    episode's running log figure against the base law, minus w_saturation times the step's share of periods at the
    current limit; 0 on divergence (the penalty is :func:`agent_reward`'s).

    For each part p of the ruler's classes (the tracking window's sum e^2 and sum |e| h, the disturbance windows'
    sum |e| h and running max |e|, the control TV and sum u^2: the accumulator's sums S_p) the running log ratio is
    L_p(j) = log((S_p(j) + eps_p) / (B_p j / K + eps_p)): B_p the base law's total over the episode's K steps,
    eps_p = CLASS_EPS B_p. The step pays -w_class sum_p w_p (L_p(j+1) - L_p(j)) with w_p (``rc[R_W + p]``) the part's
    weight in its class's log figure over the number of classes the episode has. The sum over an episode telescopes to
    -w_class sum_p w_p log((S_p(K) + eps_p) / (B_p + eps_p)): minus w_class times the ruler's log figure of the
    episode (to within the offset), 0 for the base law, and bounded by the logarithm as the ruler is.

    Args:
        st: the lane's step statistics (S_*: the sums when the step began, the saturation share).
        acc: the lane's metrics accumulator (M_*).
        rc: the lane's constants (R_*).
        j: the agent steps the episode had taken before this one.
        diverged: the loop diverged in the step.
        wts: reward weights (W_CLASS, W_SAT).
    """
    if diverged:
        return 0.0
    r = -wts[W_SAT] * st[S_SATF]
    if wts[W_CLASS] <= 0.0:
        return r
    k = rc[R_K]
    for p in range(N_PARTS):
        w = rc[R_W + p]
        if w == 0.0:
            continue
        b = rc[R_B + p]
        eps = CLASS_EPS * b
        before = _class_sum(st, acc, p, False)
        after = _class_sum(st, acc, p, True)
        num = (after + eps) / (before + eps)
        den = (b * (j + 1.0) / k + eps) / (b * j / k + eps)
        r -= wts[W_CLASS] * w * math.log(num / den)
    return r


@jit
def _class_sum(st, acc, p, now):
    """Part p's sum (R_* order) now (the accumulator) or when the step began (the step statistics)."""
    if p == R_TRK_E2:
        return acc[M_TRK_SUM_E2] if now else st[S_TRK_E2]
    if p == R_TRK_ABS:
        return acc[M_TRK_SUM_ABS] if now else st[S_TRK_ABS]
    if p == R_DST_ABS:
        return acc[M_DST_SUM_ABS] if now else st[S_DST_ABS]
    if p == R_DST_MAX:
        return acc[M_DST_MAX] if now else st[S_DST_MAX]
    if p == R_TV:
        return acc[M_TV_U] if now else st[S_TV0]
    return acc[M_SUM_U2] if now else st[S_U2]


@jit
def physical_reward(st, acc, rp, n, h, diverged, wts):
    """The physical reward of one agent step of ``n`` control periods of ``h`` [s] (the env's docstring states it):
    a function of the step's own samples and of the episode's constants, no history.

    For each class of the ruler the step's samples in its window give the class's metric pair over the step, each
    over its scale s (``rp``, P_*: the metric's physical floor, :mod:`ehss_gym.core.resolution`, plus the base law's
    level over the episode): tracking phi = 1/4 log(1 + ms/s_ms) + 1/2 log(1 + ma/s_ma) (ms, ma: the step's mean e_t^2
    and mean |e_t| in the tracking window), disturbance phi = 1/2 log(1 + peak/s_pk) + 1/2 log(1 + ma/s_dma) (peak: the
    step's largest |e_t|), effort phi = 1/2 log(1 + tv/s_tv) + 1/4 log(1 + mu2/s_u2) (tv: the step's control TV per
    second; mu2: its mean u^2); the weights are the ruler's (a square root of a mean square counts 1/2 of a log, the
    pair's two metrics 1/2 each). The step pays -w K / C sum_c (n_c / N_c) phi_c: n_c its samples in class c's window,
    N_c the episode's, K its agent steps, C its classes (docs/RL.md, "Physical reward"). 0 on divergence (the penalty
    is :func:`agent_reward`'s).

    Args:
        st: the lane's step statistics (S_*: the accumulator's sums and counts when the step began, S_EMAX).
        acc: the lane's metrics accumulator (M_*).
        rp: the lane's constants (P_*).
        n: control periods run in the step.
        h: the control period [s].
        diverged: the loop diverged in the step.
        wts: reward weights (W_PHYS).
    """
    if diverged or n <= 0.0 or rp[P_K] <= 0.0:
        return 0.0
    r = 0.0
    ntrk = acc[M_TRK_STEPS] - st[S_TRK_N]
    if ntrk > 0.0:
        ms = (acc[M_TRK_SUM_E2] - st[S_TRK_E2]) / ntrk
        ma = (acc[M_TRK_SUM_ABS] - st[S_TRK_ABS]) / (ntrk * h)
        r += ntrk / rp[P_NTRK] * (0.25 * math.log1p(ms / rp[P_MS]) + 0.5 * math.log1p(ma / rp[P_MA]))
    ndst = acc[M_DST_STEPS] - st[S_DST_N]
    if ndst > 0.0:
        ma = (acc[M_DST_SUM_ABS] - st[S_DST_ABS]) / (ndst * h)
        r += ndst / rp[P_NDST] * 0.5 * (math.log1p(st[S_EMAX] / rp[P_PK]) + math.log1p(ma / rp[P_DMA]))
    tv = (acc[M_TV_U] - st[S_TV0]) / (n * h)
    mu2 = (acc[M_SUM_U2] - st[S_U2]) / n
    r += n / rp[P_N] * (0.5 * math.log1p(tv / rp[P_TV]) + 0.25 * math.log1p(mu2 / rp[P_U2]))
    return -wts[W_PHYS] * rp[P_K] / rp[P_NCLS] * r


@jit
def memory_update(mem, e, a_prev, wts):
    """Advance a lane's memory features (MEM_*) over one agent step: the filtered error integral x' = e - x/tau with
    the step's last error ``e`` [output unit] held (exact for a held e), clipped to +-W_MEM_CLIP (anti-windup), and the
    previous step's action ``a_prev`` [-] kept as the action of the step before last."""
    x = wts[W_MEM_DECAY] * mem[MEM_EINT] + wts[W_MEM_GAIN] * e
    lim = wts[W_MEM_CLIP]
    mem[MEM_EINT] = lim if x > lim else (-lim if x < -lim else x)
    mem[MEM_APREV2] = a_prev


@jit_inline
def rate_period(u, a, c1, c2):
    """The rate action's residual after one control period: clip(u + a c1, -c2, c2) [mA], c1 = h R / RATE_TIME [mA]
    the step of a unit action, c2 = R [mA] the authority (:mod:`ehss_gym.envs.actions`)."""
    u = u + a * c1
    return c2 if u > c2 else (-c2 if u < -c2 else u)


@jit_inline
def filtered_period(u, a, c1, c2):
    """The filtered action's residual after one control period: u + c1 (c2 a - u) [mA], c1 = 1 - exp(-h / tau) [-]
    (the first-order filter's exact step for a held input), c2 = R [mA] the authority."""
    return u + c1 * (a * c2 - u)


action_period = dispatch(
    "action_period", ("mode", "u", "a", "c1", "c2"), [None if row.period is None else globals()[row.period]
                                                     for row in ACTIONS], __name__, code="mode", otherwise="u",
    doc="The residual [mA] after one control period of action mode code ``mode`` (held: ``u`` as it is).")


@jit_noalloc
def advance(n_per, h, substeps, F, H, IB, BB, events, filt, c, X, U, work, lwork, obs, elog, lay, wts):
    """Advance ``n_per`` control periods for every running lane; the env's one compiled step (:func:`advance_lanes` on
    all lanes)."""
    advance_lanes(0, F.shape[0], n_per, h, substeps, F, H, IB, BB, events, filt, c, X, U, work, lwork, obs, elog, lay,
                  wts)


@jit_noalloc
def advance_lanes(s, B_all, n_per, h, substeps, F, H, IB, BB, events, filt, c, X, U, work, lwork, obs, elog, lay,
                  wts):
    """Advance ``n_per`` control periods for every running lane of lanes s, ..., s + B - 1 (B = F.shape[0]).

    The running lanes are stepped together by :func:`ehss_gym.core.loop.lanes_period`, each from its own step
    index k (lanes reset at different times are out of phase); a lane's arithmetic does not depend on the others.
    Per lane this then writes the observation (from the controller's view at the next sample, so the agent acts on
    the freshest measurement), the reward, the agent-rate error log, and clears the run flag if the lane diverged
    (the H_INFO_OK block keeps the last finite sample).

    Args:
        n_per: control periods per agent step.
        h, substeps: control period [s] and RK4 substeps.
        s, B_all: the first of the lanes and the number of lanes in ``H``.
        F: per-lane float64 buffer (B, N_F), blocks F_* (statistics, residual [mA], reward, ...).
        H: the hot blocks H_* of all B_all lanes (loop state, rows, info, metrics, ...; :func:`hot_blocks`).
        IB: int64 buffer (N_IB, B_all), a row per quantity (IB_*): step index, agent steps taken, scratch.
        BB: per-lane bool buffer (B, N_BB): run flag (cleared on divergence), scratch.
        events: friction events (B, E, 3); filt: filter blocks (B, 3, 4, 4).
        c, X, U, work, lwork: lane scratch (made by :class:`ehss_gym.envs.lanes.Lanes`).
        obs: (B, D) float32 observations (output); lay: observation layout (3, D).
        elog: (B, T) float32 error at the last sample of each agent step.
        wts: reward weights (N_WEIGHTS,).
    """
    B = F.shape[0]
    z, plant, model, ctrl, ref, info, info_ok, peek, acc, zprev = hot_blocks(H, B_all, s, B)
    u_res = F[:, F_URES]
    run = BB[:, BB_RUN]
    act = BB[:, BB_ACT]
    pre = BB[:, BB_PRE]
    # the lanes' rows of the int buffer (one row per quantity, so each is contiguous over the lanes)
    ks, nstep, gid, kv = IB[IB_K, s:s + B], IB[IB_NSTEP, s:s + B], IB[IB_GID, s:s + B], IB[IB_KJ, s:s + B]
    n_run = 0
    for b in range(B):
        for j in range(N_STATS):
            F[b, F_STATS + j] = 0.0
        act[b] = run[b]
        gid[b] = 0 if run[b] else -1
        if run[b]:
            snapshot_classes(F[b, F_STATS:F_STATS + N_STATS], acc[b])
            n_run += 1
    if n_run == 0:
        return
    # Every running lane steps in the same calls, each from its own step index (lanes reset at different times are
    # out of phase): a lane's arithmetic does not depend on the others', so the cost does not grow with the number
    # of phases.
    for j in range(n_per):
        if wts[W_ACT_PERIOD] > 0.0:  # a residual that moves every control period (the rate and filtered modes)
            for b in range(B):
                if act[b]:
                    u_res[b] = action_period(int(wts[W_ACT_MODE]), u_res[b], F[b, F_ACT], wts[W_ACT_C1],
                                             wts[W_ACT_C2])
        for b in range(B):
            kv[b] = ks[b] + j
        # Periods alternate between the H_INFO and H_INFO_OK blocks, so the last finite period's info
        # survives a divergence in the next one without a per-period copy (lanes only ever stop).
        inf = info if j % 2 == 0 else info_ok
        n_act = lanes_period(z, kv, h, substeps, plant, model, ctrl, ref, events, filt, u_res, act, inf, acc, c, X,
                             U, zprev, work, lwork, pre, peek)
        for b in range(B):
            if act[b]:
                e = inf[b, I_E]
                F[b, F_STATS + S_SUM_E2] += e * e
                F[b, F_STATS + S_N] += 1.0
                F[b, F_STATS + S_SAT] += inf[b, I_SAT]
                # the step's current range by selects and unconditional stores: whether a period's current is a new
                # extreme is as random as the chattering current (branches on it were mispredicted)
                u = inf[b, I_UAPP]
                lo = F[b, F_STATS + S_UMIN]
                hi = F[b, F_STATS + S_UMAX]
                F[b, F_STATS + S_UMIN] = u if (j == 0) | (u < lo) else lo
                F[b, F_STATS + S_UMAX] = u if (j == 0) | (u > hi) else hi
                if wts[W_PHYS] > 0.0 and abs(inf[b, I_E_TRUE]) > F[b, F_STATS + S_EMAX]:
                    F[b, F_STATS + S_EMAX] = abs(inf[b, I_E_TRUE])
        if n_act == 0:
            break
    for b in range(B):
        if gid[b] != 0:
            continue
        # S_N finite periods ran: the last one (index S_N - 1) wrote H_INFO if its index is even
        n_ok = int(F[b, F_STATS + S_N])
        if n_ok > 0 and (n_ok - 1) % 2 == 0:
            for i in range(N_INFO):
                info_ok[b, i] = info[b, i]
        n_ran = F[b, F_STATS + S_N]
        F[b, F_STATS + S_SATF] = F[b, F_STATS + S_SAT] / n_ran if n_ran > 0.0 else 0.0
        diverged = not act[b]
        run[b] = act[b]
        ks[b] += n_per
        # the step's action [-]: the residual over its scale, or the first entry of another mode's action
        a = u_res[b] * wts[W_INV_SCALE] if wts[W_ACT_MODE] == 0.0 else F[b, F_ACT]
        F[b, F_REW] = agent_reward(a, F[b, F_APREV], F[b, F_STATS + S_N], F[b, F_STATS + S_SUM_E2],
                                   acc[b, M_TV_U] - F[b, F_STATS + S_TV0], diverged, wts)
        if wts[W_CLASS] > 0.0 or wts[W_SAT] > 0.0:
            F[b, F_REW] += class_reward(F[b, F_STATS:F_STATS + N_STATS], acc[b], F[b, F_RCLS:F_RCLS + N_RCLS],
                                        nstep[b], diverged, wts)
        if wts[W_PHYS] > 0.0:
            F[b, F_REW] += physical_reward(F[b, F_STATS:F_STATS + N_STATS], acc[b], F[b, F_RPHYS:F_RPHYS + N_RPHYS],
                                           F[b, F_STATS + S_N], h, diverged, wts)
        if wts[W_MEM_GAIN] > 0.0:
            memory_update(F[b, F_MEM:F_MEM + N_MEM], info_ok[b, I_E], F[b, F_APREV], wts)
        F[b, F_APREV] = a
        j = nstep[b]
        if j < elog.shape[1]:
            elog[b, j] = info_ok[b, I_E]
        nstep[b] = j + 1
    # the look-ahead: what each lane's controller sees at its next sample, then its observation
    peek_lanes(z, ctrl, ref, peek, u_res, BB, gid, ks, h, filt, c, work, lwork[6])
    observe_lanes(obs, peek, info_ok, F, lay, gid, lwork[0])  # the integrator's scratch rows, free by now


@jit_noalloc
def held_record(k, stop_lost, rec, rsum, F, H, IB, BB):
    """The bookkeeping after agent step ``k`` of a held action (:func:`advance_held`): each lane that stepped adds its
    reward to ``rsum`` and, if ``rec`` has a row k, copies its last finite sample (H_INFO_OK) into ``rec[k, b]``.

    Returns:
        True if a lane ended in the step: it diverged, or it has lost track and ``stop_lost`` (the env ends an
        episode that loses track).
    """
    B = F.shape[0]
    info_ok = block(H, B, H_INFO_OK, N_INFO)
    acc = block(H, B, H_ACC, N_METRICS)
    record = k < rec.shape[0]
    stop = False
    for b in range(B):
        if IB[IB_GID, b] != 0:  # did not step
            continue
        rsum[b] += F[b, F_REW]
        if record and b < rec.shape[1]:
            for i in range(N_INFO):
                rec[k, b, i] = info_ok[b, i]
        if not BB[b, BB_RUN] or (stop_lost and acc[b, M_LOST] > 0.0):
            stop = True
    return stop


@jit_noalloc
def advance_held(n_max, stop_lost, rec, rsum, n_per, h, substeps, F, H, IB, BB, events, filt, c, X, U, work, lwork,
                 obs, elog, lay, wts):
    """Up to ``n_max`` agent steps of :func:`advance` with the actions held, in one call, stopping after the first step
    in which a lane ends (:func:`held_record`, which keeps the rewards and samples). Returns the steps taken."""
    for k in range(n_max):
        advance(n_per, h, substeps, F, H, IB, BB, events, filt, c, X, U, work, lwork, obs, elog, lay, wts)
        if held_record(k, stop_lost, rec, rsum, F, H, IB, BB):
            return k + 1
    return n_max


@nb.njit(parallel=True, cache=True, error_model="numpy")
def advance_chunks(chunk, n_per, h, substeps, F, H, IB, BB, events, filt, c, X, U, work, lwork, obs, elog, lay,
                   wts):
    """:func:`advance` on chunks of ``chunk`` lanes in parallel; per-chunk scratch c, X, U, work, lwork."""
    n_chunks = c.shape[0]
    B_all = F.shape[0]
    for i in nb.prange(n_chunks):
        s = i * chunk
        e = s + chunk
        advance_lanes(s, B_all, n_per, h, substeps, F[s:e], H, IB, BB[s:e], events[s:e], filt[s:e], c[i], X[i],
                      U[i], work[i], lwork[i], obs[s:e], elog[s:e], lay, wts)


# The vector env's bookkeeping around its compiled step, one pass over the sub-envs each: what numpy did as about
# thirty whole-array operations, each a Python call of about a microsecond, at 256 sub-envs a tenth of the step.


@jit_noalloc
def vector_actions(a, autoreset, ended, out, clipped, stepped, n_clipped, run):
    """Check and clip the vector env's actions a (N, k) in [-1, 1] into ``out``, then launch the step: per sub-env b,
    ``stepped[b]``: it steps (neither resetting nor ended); ``clipped[b]``: it steps and an entry of its action was
    outside [-1, 1], counted in ``n_clipped[b]``; a sub-env that does not step has its run flag ``run[b]`` cleared
    (a sub-env reset after this call is stopped again by the caller). Returns (sub-envs resetting, sub-envs that
    step), or (0, -1), having written nothing, if an action is NaN."""
    N = a.shape[0]
    for b in range(N):
        for j in range(a.shape[1]):
            if math.isnan(a[b, j]):
                return 0, -1
    n_reset = 0
    n_step = 0
    for b in range(N):
        steps = not (autoreset[b] or ended[b])
        stepped[b] = steps
        n_reset += autoreset[b]
        n_step += steps
        c = False
        for j in range(a.shape[1]):
            v = a[b, j]
            if v > 1.0 or v < -1.0:
                c = True
            out[b, j] = min(max(v, -1.0), 1.0)
        clipped[b] = c and steps
        n_clipped[b] += clipped[b]
        if not steps:
            run[b] = False
    return n_reset, n_step


@jit_noalloc
def vector_ends(run, acc, T, steps, stepped, autoreset, n, stop_lost, info_ok, stats, rew, flags, info_t, stats_t,
                rewards):
    """After the vector env's step of n agent steps: per sub-env its flags (rows: diverged, lost track, terminated,
    truncated, ended), its step count and run flag (a resetting sub-env runs again), its reward (``rew[b]`` if it
    stepped, else 0) and the info's transposed copies of the last finite samples and step statistics. Returns how many
    sub-envs ended."""
    n_end = 0
    for b in range(flags.shape[1]):
        s = stepped[b]
        rewards[b] = rew[b] if s else 0.0
        flags[0, b] = s and not run[b]
        lost = acc[b, M_LOST] > 0.0
        flags[1, b] = lost
        if stop_lost and s and lost:
            run[b] = False
        flags[2, b] = s and not run[b]
        if s:
            steps[b] += n
        flags[3, b] = s and run[b] and steps[b] >= T[b]
        flags[4, b] = flags[2, b] or flags[3, b]
        n_end += flags[4, b]
        if autoreset[b]:
            run[b] = True
    # a row of the copy at a time: down a column, the rows (N doubles apart) share a few cache sets at N = 256
    for i in range(info_t.shape[0]):
        for b in range(info_t.shape[1]):
            info_t[i, b] = info_ok[b, i]
    for i in range(stats_t.shape[0]):
        for b in range(stats_t.shape[1]):
            stats_t[i, b] = stats[b, i]
    return n_end
