"""Tracking and control metrics of a closed-loop run.

Most metrics are accumulated at the full control rate inside the compiled loop
(layout ``M_*``, :func:`accumulate`), so logging decimation does not bias them; :func:`summarize_acc` turns an
accumulator row into the metrics. Recovery times need the time history and use the logged trajectory.

Definitions (e = y - y_d in the output unit, u the applied current in mA, h the
control period, T the simulated time):

- ``rmse``: sqrt(mean e^2) over all control steps; ``rmse_nominal`` over the
  steps with no friction event active; ``rmse_quiet`` over the steps past the
  start-up (t >= 0.2 s) and neither in a friction event nor within 0.2 s after
  one ends (the tracking error itself, without the friction transients that
  dominate ``rmse_nominal`` once the loop tracks to ~1e-5; NaN if no such step).
- ``rmse_nominal_settled``: the same over the steps past the start-up (t >= 0.2 s) with no friction event
  active (the nominal RMSE with the start-up excluded; NaN if no such step).
- ``lost_track``: the loop lost track: once past the start-up (t >= 0.2 s), the RMS of e over a sliding
  window (an exponential moving mean of e^2, time constant 0.1 s, starting empty at 0.2 s) exceeded the
  scenario's bound ``Scenario.lost_track`` * the reference's amplitude (1 x by default: an error as large as
  the signal to track). ``t_lost_track`` [s]: when it first did (None if never). A diverged run stops first
  and is reported as diverged; a lost track only flags a run that goes on (a saturated oscillation within
  the state bounds, for instance).
- ``rmse_true``, ``rmse_quiet_true``, ``max_abs_e_friction_true``: the same with the true error (the
  plant's output, no sensor noise; e above is the error the controller measures). ``rmse_r``: the true
  output against the raw reference r instead of the reference model's y_d (independent of the reference
  model: of its start, its lag and a shaper).
- ``iae``: sum |e| h;  ``itae``: sum t |e| h.
- The metric classes, on the true error e_t over windows that partition the control samples (layout WIN_*):
  the *start-up* t < 0.2 s; past it, a *disturbance* window from each friction event's start to 0.2 s after its
  end (whatever the event's amplitude: an event of amplitude 0 keeps its window); *tracking* the rest.
  ``trk_rmse`` = sqrt(mean e_t^2) and ``trk_iae`` = sum |e_t| h over the tracking window; ``dst_peak`` = max
  |e_t| and ``dst_iae`` = sum |e_t| h over the disturbance windows; ``su_rmse``, ``su_iae``, ``su_peak`` over the
  start-up. NaN for a window with no sample (IAE included: an episode without friction has no disturbance
  class). ``steps_startup``, ``steps_disturbance``, ``steps_tracking``: the samples in each (they add up to
  ``steps``); ``t_tracking``, ``t_disturbance`` [s]: the tracking and disturbance windows' durations.
  ``iae_r``: sum |y - r| h, the true output against the raw reference.
- ``max_abs_e``: max |e|; ``max_abs_e_friction``: max |e| while friction is on.
- ``recovery_on`` / ``recovery_off``: settling time after the first friction
  edge (on / off): the time until |e| enters, and then stays in, a band of
  ``max(2 * max|e| of the second before friction first switches on,
  RECOVERY_SHARE * the peak |e| after the edge)`` (floor 1e-9), measured up to
  the next edge. ``inf`` = never. The share of the edge's own peak makes the band
  meaningful for a loop that tracks far better than the friction offset it is
  left with while the friction is on: such a loop has no integral action, so its
  error cannot return to its pre-friction level until the friction switches off.
- ``tv_u``: control total variation sum |u_k - u_{k-1}| [mA];
  ``tv_u_rate`` = tv_u / T [mA/s], the chattering index.
- ``peak_u``: max |commanded u|; ``peak_u_applied``; ``rms_u`` [mA].
- ``saturation``: share of steps on which the current limit was active.
- ``v_decrease``: share of steps on which V fell from the previous step.
- ``v_model_decrease``: share of steps on which the model's Lyapunov condition holds at the applied current: V' = a +
  b u < 0 (sign(s) (psi + G u) < 0), or s = 0, where V = 0 is its minimum and V' = 0 at every current
  (:func:`model_v_decreasing`): what the Lyapunov-constrained residual keeps (``Scenario.lyapunov_kappa``) wherever
  the law itself makes V decrease within the current limit.
- with a step reference, ``step_rise_time``, ``step_settling_time``, ``step_overshoot``, ``step_peak_time`` and
  ``step_steady_state_error`` (:func:`step_summary`).
"""

from __future__ import annotations

import math

import numpy as np

from .jit import jit_inline
from .layout import (
    DIV_NAMES,
    DIV_NONE,
    EV_AMP,
    EV_END,
    EV_START,
    I_E,
    I_E_R,
    I_E_TRUE,
    I_G,
    I_PSI,
    I_S,
    I_SAT,
    I_T,
    I_UAPP,
    I_UCMD,
    I_V,
    LOST_TRACK_WINDOW,
    M_DIVERGED,
    M_DST_MAX,
    M_DST_STEPS,
    M_DST_SUM_ABS,
    M_LAST_U,
    M_LAST_V,
    M_LOST,
    M_LOST_BOUND,
    M_LOST_EMA,
    M_MAX_E,
    M_MAX_E_FRIC,
    M_MAX_E_FRIC_TRUE,
    M_N_SAT,
    M_N_VDEC,
    M_N_VMODEL_DEC,
    M_PEAK_UAPP,
    M_PEAK_UCMD,
    M_STEPS,
    M_STEPS_FRIC,
    M_STEPS_NOFRIC,
    M_STEPS_QUIET,
    M_STEPS_SETTLED,
    M_SU_MAX,
    M_SU_STEPS,
    M_SU_SUM_ABS,
    M_SU_SUM_E2,
    M_SUM_ABS_E,
    M_SUM_ABS_ER,
    M_SUM_E2,
    M_SUM_E2_NOFRIC,
    M_SUM_E2_QUIET,
    M_SUM_E2_QUIET_TRUE,
    M_SUM_E2_SETTLED,
    M_SUM_E2_TRUE,
    M_SUM_ER2,
    M_SUM_T_ABS_E,
    M_SUM_U2,
    M_T_DIVERGED,
    M_T_LOST,
    M_TRK_STEPS,
    M_TRK_SUM_ABS,
    M_TRK_SUM_E2,
    M_TV_U,
    QUIET_GUARD,
    QUIET_STARTUP,
    R_A1,
    R_T0,
    WIN_DISTURBANCE,
    WIN_STARTUP,
    WIN_TRACKING,
)
from .response import step_metrics

RECOVERY_SHARE = 0.1  # the settling band includes this share of the edge's peak |e| (a 90 % recovery)


# --- The accumulator, at the control rate (compiled) ----------------------------------------------------


def init_accumulator(acc: np.ndarray, lost_track_bound: float) -> None:
    """Set the parameters of a fresh (zeroed) accumulator row (layout M_*): the lost-track bound [output unit]."""
    acc[M_T_DIVERGED] = -1.0
    acc[M_LOST_BOUND] = lost_track_bound
    acc[M_T_LOST] = -1.0


@jit_inline
def accumulate_window(acc, win, et, h):
    """Fold the true error ``et`` [output unit] of one sample into its metric window's class (layout WIN_*, M_SU_*,
    M_DST_*, M_TRK_*): steps, sum e^2, sum |e| h [output unit * s] and max |e|."""
    ae = abs(et)
    if win == WIN_TRACKING:
        acc[M_TRK_STEPS] += 1.0
        acc[M_TRK_SUM_E2] += et * et
        acc[M_TRK_SUM_ABS] += ae * h
    elif win == WIN_DISTURBANCE:
        acc[M_DST_STEPS] += 1.0
        acc[M_DST_SUM_ABS] += ae * h
        if ae > acc[M_DST_MAX]:
            acc[M_DST_MAX] = ae
    else:
        acc[M_SU_STEPS] += 1.0
        acc[M_SU_SUM_E2] += et * et
        acc[M_SU_SUM_ABS] += ae * h
        if ae > acc[M_SU_MAX]:
            acc[M_SU_MAX] = ae


@jit_inline
def accumulate(acc, info, h, k, events):
    """Fold one control step's info into the metrics accumulator (layout M_*): what :func:`summarize_acc` reads.

    Called once per control period and lane by :func:`ehss_gym.core.loop.lanes_period`, after the period's
    divergence checks passed. ``h`` is the control period [s], ``k`` the step index, ``events`` the run's friction
    events (E, 3), which classify the sample: in a friction event, or *quiet* (past the start-up, and neither in an
    event nor within QUIET_GUARD after one ends).
    """
    t = info[I_T]
    fric_on = False
    quiet = t >= QUIET_STARTUP
    win = WIN_TRACKING if quiet else WIN_STARTUP
    for i in range(events.shape[0]):
        if events[i, EV_START] <= t < events[i, EV_END] + QUIET_GUARD:
            if win == WIN_TRACKING:  # an event's window counts whatever its amplitude (layout WIN_*)
                win = WIN_DISTURBANCE
            if events[i, EV_AMP] != 0.0:
                quiet = False
                if t < events[i, EV_END]:
                    fric_on = True
    e = info[I_E]
    ae = abs(e)
    et = info[I_E_TRUE]
    acc[M_SUM_E2_TRUE] += et * et
    acc[M_SUM_ER2] += info[I_E_R] * info[I_E_R]
    acc[M_SUM_ABS_ER] += abs(info[I_E_R]) * h
    accumulate_window(acc, win, et, h)
    acc[M_STEPS] += 1.0
    acc[M_SUM_E2] += e * e
    acc[M_SUM_ABS_E] += ae * h
    acc[M_SUM_T_ABS_E] += t * ae * h
    if ae > acc[M_MAX_E]:
        acc[M_MAX_E] = ae
    if fric_on:
        acc[M_STEPS_FRIC] += 1.0
        if ae > acc[M_MAX_E_FRIC]:
            acc[M_MAX_E_FRIC] = ae
        if abs(et) > acc[M_MAX_E_FRIC_TRUE]:
            acc[M_MAX_E_FRIC_TRUE] = abs(et)
    else:
        acc[M_STEPS_NOFRIC] += 1.0
        acc[M_SUM_E2_NOFRIC] += e * e
    if quiet:
        acc[M_STEPS_QUIET] += 1.0
        acc[M_SUM_E2_QUIET] += e * e
        acc[M_SUM_E2_QUIET_TRUE] += et * et
    if t >= QUIET_STARTUP:
        if not fric_on:
            acc[M_STEPS_SETTLED] += 1.0
            acc[M_SUM_E2_SETTLED] += e * e
        # lost track: the windowed RMS of e above its bound (from the start-up's end; the window starts empty)
        acc[M_LOST_EMA] += (e * e - acc[M_LOST_EMA]) * min(1.0, h / LOST_TRACK_WINDOW)
        if acc[M_LOST] == 0.0 and acc[M_LOST_EMA] > acc[M_LOST_BOUND] * acc[M_LOST_BOUND]:
            acc[M_LOST] = 1.0
            acc[M_T_LOST] = t
    u = info[I_UAPP]
    if k > 0:
        acc[M_TV_U] += abs(u - acc[M_LAST_U])
        # a select and an unconditional store, not a branch: whether V fell is as random as the noise, and a
        # mispredicted branch per lane and period cost more than the rest of this count (adding 0.0 to a count
        # leaves its bits as they were)
        acc[M_N_VDEC] += 1.0 if info[I_V] < acc[M_LAST_V] else 0.0
    acc[M_LAST_U] = u
    acc[M_LAST_V] = info[I_V]
    uc = abs(info[I_UCMD])
    if uc > acc[M_PEAK_UCMD]:
        acc[M_PEAK_UCMD] = uc
    if abs(u) > acc[M_PEAK_UAPP]:
        acc[M_PEAK_UAPP] = abs(u)
    acc[M_SUM_U2] += u * u
    acc[M_N_SAT] += info[I_SAT]
    acc[M_N_VMODEL_DEC] += model_v_decreasing(info)


@jit_inline
def model_v_decreasing(info):
    """1.0 if the model's Lyapunov condition holds at the sample's applied current, else 0.0: V' < 0, or s = 0.

    V' = (s/sigma)^(n-1) (psi + G u) / sigma with n even has the sign of s (psi + G u), taken by signs (a product of
    tiny values could underflow to 0). At s = 0 exactly V = 0 is its minimum and V' = 0 at every current, so no
    current can do better: the condition (V' < 0 wherever V > 0) holds there. A bumpless start has s = 0 at t = 0
    (the reference model starts at the measured output and its estimated derivatives).
    """
    s = info[I_S]
    x = info[I_PSI] + info[I_G] * info[I_UAPP]
    # the signs combined with & and |, which do not short-circuit: the signs of s and x change from sample to sample
    # with the noise, so branches on them were mispredicted about as often as not
    return 1.0 if ((s > 0.0) & (x < 0.0)) | ((s < 0.0) & (x > 0.0)) | (s == 0.0) else 0.0


# --- The summary, from the accumulator and the logged trajectory ---------------------------------------


def recovery_times(t: np.ndarray, e: np.ndarray, friction) -> tuple[float, float]:
    """Settling time after the first friction switch-on and switch-off [s]; inf if never (module docstring)."""
    active = [ev for ev in friction if ev[0] > 0.0]
    if not active or len(t) < 3:
        return math.nan, math.nan
    t_on = min(ev[1] for ev in active)
    t_off = min(ev[2] for ev in active if ev[1] == t_on)
    pre = (t >= t_on - 1.0) & (t < t_on)
    pre_band = 2.0 * float(np.max(np.abs(e[pre]))) if pre.any() else 0.0

    def settle(t_edge: float, t_stop: float) -> float:
        sel = (t >= t_edge) & (t < t_stop)
        if not sel.any():
            return math.nan
        ae = np.abs(e[sel])
        band = max(pre_band, RECOVERY_SHARE * float(np.max(ae)), 1e-9)
        outside = ae > band
        if not outside.any():
            return 0.0
        last = np.nonzero(outside)[0][-1]
        if last == sel.sum() - 1:
            return math.inf
        return float(t[sel][last + 1] - t_edge)

    later_edges = [ev[1] for ev in active if ev[1] > t_on] + [math.inf]
    return settle(t_on, t_off), settle(t_off, min(later_edges))


def summarize(traj) -> dict:
    """The metrics dict of a :class:`~ehss_gym.core.sim.Trajectory` (see module docstring); with a step reference
    also its step-response metrics (:func:`step_summary`)."""
    out = summarize_acc(traj.acc, traj.scenario, traj.t, traj.e)
    if traj.scenario.reference.family == "step":
        out.update(step_summary(traj))
    return out


def step_summary(traj) -> dict:
    """Step-response metrics of the output y of a run with a step reference, from the logged trajectory.

    The step is the reference's: from its offset to offset + amplitude at its step time
    (:func:`ehss_gym.core.response.step_metrics`; the response includes the reference model's lag, as a
    control engineer measures r -> y). Keys ``step_rise_time`` [s], ``step_settling_time`` [s],
    ``step_overshoot`` [%], ``step_peak_time`` [s], ``step_steady_state_error`` [output unit].
    """
    ref = traj.scenario.reference
    y0 = ref.offset
    m = step_metrics(traj.t, traj.y, float(ref.spec[R_T0]), y0, y0 + float(ref.spec[R_A1]))
    return {f"step_{k}": v for k, v in m.items() if k != "final_value"}


def summarize_acc(a: np.ndarray, sc, t: np.ndarray | None = None, e: np.ndarray | None = None) -> dict:
    """Metrics from an accumulator row (layout M_*) of scenario ``sc``.

    ``t`` and ``e`` (a sampled error history) are needed only for the recovery
    times; without them those are NaN.
    """
    steps = max(a[M_STEPS], 1.0)
    T = steps * sc.control_period
    out = {
        "diverged": bool(a[M_DIVERGED] != DIV_NONE),
        "divergence_reason": DIV_NAMES[int(a[M_DIVERGED])],
        "t_diverged": float(a[M_T_DIVERGED]) if a[M_DIVERGED] else None,
        "rmse": float(math.sqrt(a[M_SUM_E2] / steps)),
        "rmse_nominal": math.sqrt(a[M_SUM_E2_NOFRIC] / max(a[M_STEPS_NOFRIC], 1.0)),
        "rmse_nominal_settled": (math.sqrt(a[M_SUM_E2_SETTLED] / a[M_STEPS_SETTLED]) if a[M_STEPS_SETTLED]
                                 else math.nan),
        "lost_track": bool(a[M_LOST] > 0.0),
        "t_lost_track": float(a[M_T_LOST]) if a[M_LOST] > 0.0 else None,
        "rmse_quiet": math.sqrt(a[M_SUM_E2_QUIET] / a[M_STEPS_QUIET]) if a[M_STEPS_QUIET] else math.nan,
        "rmse_true": float(math.sqrt(a[M_SUM_E2_TRUE] / steps)),
        "rmse_r": float(math.sqrt(a[M_SUM_ER2] / steps)),
        "rmse_quiet_true": (math.sqrt(a[M_SUM_E2_QUIET_TRUE] / a[M_STEPS_QUIET]) if a[M_STEPS_QUIET]
                            else math.nan),
        "iae": float(a[M_SUM_ABS_E]),
        "itae": float(a[M_SUM_T_ABS_E]),
        "max_abs_e": float(a[M_MAX_E]),
        "max_abs_e_friction": float(a[M_MAX_E_FRIC]) if a[M_STEPS_FRIC] else math.nan,
        "max_abs_e_friction_true": float(a[M_MAX_E_FRIC_TRUE]) if a[M_STEPS_FRIC] else math.nan,
        "tv_u": float(a[M_TV_U]),
        "tv_u_rate": float(a[M_TV_U] / T),
        "peak_u": float(a[M_PEAK_UCMD]),
        "peak_u_applied": float(a[M_PEAK_UAPP]),
        "rms_u": math.sqrt(a[M_SUM_U2] / steps),
        "saturation": float(a[M_N_SAT] / steps),
        "v_decrease": float(a[M_N_VDEC] / max(steps - 1.0, 1.0)),
        "v_model_decrease": float(a[M_N_VMODEL_DEC] / steps),
        "steps": int(steps),
        "iae_r": float(a[M_SUM_ABS_ER]),
    }
    out.update(window_metrics(a))
    # the windows' durations [s] (the ruler floors an IAE at an error floor held over its window)
    out["t_tracking"] = out["steps_tracking"] * sc.control_period
    out["t_disturbance"] = out["steps_disturbance"] * sc.control_period
    on, off = (math.nan, math.nan) if t is None or e is None else recovery_times(t, e, sc.friction)
    out["recovery_on"] = on
    out["recovery_off"] = off
    return out


def window_metrics(a: np.ndarray) -> dict:
    """The metric classes of an accumulator row (layout M_SU_*, M_DST_*, M_TRK_*; module docstring); NaN for a window
    with no sample."""
    n_su, n_dst, n_trk = (float(a[i]) for i in (M_SU_STEPS, M_DST_STEPS, M_TRK_STEPS))
    nan = math.nan
    return {
        "trk_rmse": math.sqrt(a[M_TRK_SUM_E2] / n_trk) if n_trk else nan,
        "trk_iae": float(a[M_TRK_SUM_ABS]) if n_trk else nan,
        "dst_peak": float(a[M_DST_MAX]) if n_dst else nan,
        "dst_iae": float(a[M_DST_SUM_ABS]) if n_dst else nan,
        "su_rmse": math.sqrt(a[M_SU_SUM_E2] / n_su) if n_su else nan,
        "su_iae": float(a[M_SU_SUM_ABS]) if n_su else nan,
        "su_peak": float(a[M_SU_MAX]) if n_su else nan,
        "steps_startup": int(n_su), "steps_disturbance": int(n_dst), "steps_tracking": int(n_trk),
    }


def format_summary(m: dict, unit: str) -> str:
    """A short human-readable summary block."""
    lines = []
    if m["diverged"]:
        lines.append(f"DIVERGED at t = {m['t_diverged']:.6g} s ({m['divergence_reason']}); metrics up to then:")
    elif m.get("lost_track"):
        lines.append(f"LOST TRACK at t = {m['t_lost_track']:.6g} s (windowed RMS of e above the lost-track bound)")
    lines += [
        f"  RMSE                  {m['rmse']:.4g} {unit}",
        f"  max |e|               {m['max_abs_e']:.4g} {unit}",
        f"  max |e| in friction   {m['max_abs_e_friction']:.4g} {unit}",
        f"  IAE                   {m['iae']:.4g} {unit}*s",
        f"  control TV            {m['tv_u']:.4g} mA  ({m['tv_u_rate']:.4g} mA/s)",
        f"  peak |u| commanded    {m['peak_u']:.4g} mA",
        f"  saturation fraction   {m['saturation']:.4f}",
    ]
    if "step_rise_time" in m:
        lines += [
            f"  step rise time        {m['step_rise_time']:.4g} s  (10-90 %)",
            f"  step settling time    {m['step_settling_time']:.4g} s  (2 % band)",
            f"  step overshoot        {m['step_overshoot']:.4g} %",
            f"  steady-state error    {m['step_steady_state_error']:.4g} {unit}",
        ]
    return "\n".join(lines)
