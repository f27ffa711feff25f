"""Tracking and control metrics of a closed-loop run.

Most metrics are accumulated at the full control rate inside the compiled loop
(layout ``M_*``), so logging decimation does not bias them. Recovery times need
the time history and use the logged trajectory.

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
  ``steps``). ``iae_r``: sum |y - r| h, the true output against the raw reference.
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
- with a step reference, ``step_rise_time``, ``step_settling_time``, ``step_overshoot``, ``step_peak_time`` and
  ``step_steady_state_error`` (:func:`step_summary`).
"""

from __future__ import annotations

import math

import numpy as np

from . import layout as L
from .response import step_metrics

RECOVERY_SHARE = 0.1  # the settling band includes this share of the edge's peak |e| (a 90 % recovery)


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
    m = step_metrics(traj.t, traj.y, float(ref.spec[L.R_T0]), y0, y0 + float(ref.spec[L.R_A1]))
    return {f"step_{k}": v for k, v in m.items() if k != "final_value"}


def summarize_acc(a: np.ndarray, sc, t: np.ndarray | None = None, e: np.ndarray | None = None) -> dict:
    """Metrics from an accumulator row (layout M_*) of scenario ``sc``.

    ``t`` and ``e`` (a sampled error history) are needed only for the recovery
    times; without them those are NaN.
    """
    steps = max(a[L.M_STEPS], 1.0)
    T = steps * sc.control_period
    out = {
        "diverged": bool(a[L.M_DIVERGED] != L.DIV_NONE),
        "divergence_reason": L.DIV_NAMES[int(a[L.M_DIVERGED])],
        "t_diverged": float(a[L.M_T_DIVERGED]) if a[L.M_DIVERGED] else None,
        "rmse": float(math.sqrt(a[L.M_SUM_E2] / steps)),
        "rmse_nominal": math.sqrt(a[L.M_SUM_E2_NOFRIC] / max(a[L.M_STEPS_NOFRIC], 1.0)),
        "rmse_nominal_settled": (math.sqrt(a[L.M_SUM_E2_SETTLED] / a[L.M_STEPS_SETTLED]) if a[L.M_STEPS_SETTLED]
                                 else math.nan),
        "lost_track": bool(a[L.M_LOST] > 0.0),
        "t_lost_track": float(a[L.M_T_LOST]) if a[L.M_LOST] > 0.0 else None,
        "rmse_quiet": math.sqrt(a[L.M_SUM_E2_QUIET] / a[L.M_STEPS_QUIET]) if a[L.M_STEPS_QUIET] else math.nan,
        "rmse_true": float(math.sqrt(a[L.M_SUM_E2_TRUE] / steps)),
        "rmse_r": float(math.sqrt(a[L.M_SUM_ER2] / steps)),
        "rmse_quiet_true": (math.sqrt(a[L.M_SUM_E2_QUIET_TRUE] / a[L.M_STEPS_QUIET]) if a[L.M_STEPS_QUIET]
                            else math.nan),
        "iae": float(a[L.M_SUM_ABS_E]),
        "itae": float(a[L.M_SUM_T_ABS_E]),
        "max_abs_e": float(a[L.M_MAX_E]),
        "max_abs_e_friction": float(a[L.M_MAX_E_FRIC]) if a[L.M_STEPS_FRIC] else math.nan,
        "max_abs_e_friction_true": float(a[L.M_MAX_E_FRIC_TRUE]) if a[L.M_STEPS_FRIC] else math.nan,
        "tv_u": float(a[L.M_TV_U]),
        "tv_u_rate": float(a[L.M_TV_U] / T),
        "peak_u": float(a[L.M_PEAK_UCMD]),
        "peak_u_applied": float(a[L.M_PEAK_UAPP]),
        "rms_u": math.sqrt(a[L.M_SUM_U2] / steps),
        "saturation": float(a[L.M_N_SAT] / steps),
        "v_decrease": float(a[L.M_N_VDEC] / max(steps - 1.0, 1.0)),
        "steps": int(steps),
        "iae_r": float(a[L.M_SUM_ABS_ER]),
    }
    out.update(window_metrics(a))
    on, off = (math.nan, math.nan) if t is None or e is None else recovery_times(t, e, sc.friction)
    out["recovery_on"] = on
    out["recovery_off"] = off
    return out


def window_metrics(a: np.ndarray) -> dict:
    """The metric classes of an accumulator row (layout M_SU_*, M_DST_*, M_TRK_*; module docstring); NaN for a window
    with no sample."""
    n_su, n_dst, n_trk = (float(a[i]) for i in (L.M_SU_STEPS, L.M_DST_STEPS, L.M_TRK_STEPS))
    nan = math.nan
    return {
        "trk_rmse": math.sqrt(a[L.M_TRK_SUM_E2] / n_trk) if n_trk else nan,
        "trk_iae": float(a[L.M_TRK_SUM_ABS]) if n_trk else nan,
        "dst_peak": float(a[L.M_DST_MAX]) if n_dst else nan,
        "dst_iae": float(a[L.M_DST_SUM_ABS]) if n_dst else nan,
        "su_rmse": math.sqrt(a[L.M_SU_SUM_E2] / n_su) if n_su else nan,
        "su_iae": float(a[L.M_SU_SUM_ABS]) if n_su else nan,
        "su_peak": float(a[L.M_SU_MAX]) if n_su else nan,
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
