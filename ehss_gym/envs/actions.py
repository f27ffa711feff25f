"""The agent's action modes (the env setting ``action``): one table row plus its functions per mode.

A mode says what the agent's action a in [-1, 1]^k does to the loop. Its row of :data:`ACTIONS` names the mode, its
action's size, its bound (unit, default per task, and the measurement the default comes from), its function that
writes an agent step's action into the lanes (:attr:`ActionMode.write`, in :mod:`ehss_gym.envs.lanes`) and, for a
residual that moves within the agent step, its compiled function that advances the residual every control period
(:attr:`ActionMode.period`, in :mod:`ehss_gym.envs.kernels`, called through its ``action_period``). Its code, what
the kernel reads, is its index in the table. Plain data (no numba): the settings' validation reads it.

- ``current`` (the default; today's action): the residual current ``residual_scale * a`` [mA], held over the agent
  step.
- ``rate``: a is the residual's rate of change, ``a * R / RATE_TIME`` [mA/s]; the residual r is integrated every
  control period (r <- clip(r + h a R / RATE_TIME, -R, R)), so it is continuous; R = ``action_bound`` [mA].
- ``filtered``: the residual is a first-order filter (time constant :data:`FILTER_TAU`) of ``R a`` [mA], discretised
  exactly for the held action: r <- r + (1 - exp(-h / tau)) (R a - r); |r| <= R.
- ``reference``: the law's reference is shifted by delta = ``D a`` [output unit], D = ``action_bound``: the shift
  drives a copy of the reference model, so the law tracks y_d + Delta with Delta and its derivatives consistent
  (:func:`ehss_gym.core.controller.reference_shift`); the ruler and the reward still measure against y_d. The route
  for a sensor delay of d samples: the law puts the measured output, y(t - d h), on its reference, so the true output
  leads y_d by about d h y_d'; delta = -d h r' (about -d h y_d') takes that back.
- ``schedule``: the law's gains scaled at the agent rate (gain scheduling): a_0 scales the boundary layer's width (the
  smoothing width and the adaptive layer's gain), a_1 sigma and, with the disturbance observer on (``dob_hz`` > 0),
  a_2 its bandwidth; each factor is f = hi^a for a >= 0 and lo^(-a) for a < 0 within its range of
  :data:`SCHEDULE_RANGES` (so a = 0 is the factor 1 exactly).
- ``reference-schedule``: both in one action (a_0 the reference mode's shift, a_1 and a_2 the schedule mode's width
  and sigma factors): the route that compensates a delay and widens the boundary layer where no friction edge needs
  it. The disturbance observer's bandwidth is not scheduled in this mode (its action has 3 entries with the observer
  on or off).
- ``compensation``: the loop's compensators of the unmodelled valve and sensor scaled at the agent rate, and the
  schedule mode's width and sigma: a_0 scales the valve inverse's threshold and hysteresis, a_1 the reference delay,
  each by the factor 1 + a in [0, 2] (a = -1 switches it off, a = 0 keeps the loop's setting); a_2 and a_3 are the
  schedule mode's width and sigma factors. The route for a residual on top of a scripted compensator (``vinv-n2``,
  ``dcomp-n2``): it can weaken a compensation where the episode's valve or sensor does not need it (a valve with no
  dead band, where the inverse only adds current) and strengthen it where they need more (a delay of two samples
  against a compensation of one). It needs a compensator on (``reference_delay`` or ``inverse_threshold`` /
  ``inverse_hysteresis`` > 0); the scaled delay is at most :data:`~ehss_gym.core.layout.MAX_DELAY` samples.

Every mode with a = 0 throughout is the base law, bit for bit (tests/test_actions.py). The bounds' defaults and their
sources are in the rows (docs/ENV.md, "Action modes", has the measurement).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

RATE_TIME = 0.01  # [s] the rate mode's full authority R is reached in this time from 0: its rate bound is R / RATE_TIME
FILTER_TAU = 0.01  # [s] the filtered mode's time constant (the servo valve's own, Table I: 10 ms)
# The schedule mode's factors: (what it scales, lowest factor, highest factor). The width's range covers the headroom
# table's per-episode best widths (reports/headroom: medians 18x the default in velocity on the held-out suite, 270x
# in position on the unmodelled suite); sigma and the observer's bandwidth a decade either way.
SCHEDULE_RANGES = (("width", 0.1, 1000.0), ("sigma", 0.1, 10.0), ("observer", 0.1, 10.0))
# their logarithms, taken once (every agent step of the mode uses them)
_LOG_LO = np.log([r[1] for r in SCHEDULE_RANGES])
_LOG_HI = np.log([r[2] for r in SCHEDULE_RANGES])
_NEG_LOG_LO = -_LOG_LO


@dataclass(frozen=True)
class ActionMode:
    """An action mode: what the agent's action does (see the module docstring).

    Attributes:
        name: its name (the env's ``action`` setting).
        doc: one line: what the action is.
        unit: the unit of its bound (``action_bound``); "" if it has none.
        bound: its default bound per task, ((task, value), ...); () if it has none.
        source: the measurement the default bound comes from.
        write: its function in :mod:`ehss_gym.envs.lanes` that writes an agent step's actions (n, k) into the lanes
            ``idx`` (``write(lanes, idx, a)``).
        period: its compiled per-control-period residual update ``(u, a, c1, c2) -> u`` [mA] in
            :mod:`ehss_gym.envs.kernels`, or None (the action is held over the agent step).
        resense: the action changes what the law computes at a sample (not only the residual added to it): the
            env's look-ahead of the step's first sample, made with the last action, is computed again.
        dims: the size k of its action.
        observer_dim: one more action entry when the disturbance observer is on (``dob_hz`` > 0).
        shift: its first action entry shifts the law's reference (the law's reference shift is on).
        schedule: its entries from ``schedule`` on are the schedule mode's factors (None: it schedules nothing).
        entries: the names of its action's entries in the observation (``action_<name>``); () names them from
            ``shift`` and ``schedule``.
        compensators: it scales the loop's compensators (one must be on).
    """

    name: str
    doc: str
    unit: str
    bound: tuple
    source: str
    write: str
    period: str | None = None
    resense: bool = False
    dims: int = 1
    observer_dim: bool = False
    shift: bool = False
    schedule: int | None = None
    entries: tuple = ()
    compensators: bool = False

    def default_bound(self, task: str) -> float | None:
        """The default ``action_bound`` for ``task`` (None for a mode without a bound)."""
        return dict(self.bound).get(task) if self.bound else None


def period_constants(mode: ActionMode, bound: float | None, h: float) -> tuple[float, float]:
    """(c1, c2) of ``mode``'s per-period update at control period ``h`` [s] and bound R [mA] (0, 0 without one):
    the rate mode's step h R / RATE_TIME [mA] and R, the filtered mode's 1 - exp(-h / FILTER_TAU) [-] and R."""
    if mode.period == "rate_period":
        return h * bound / RATE_TIME, bound
    if mode.period == "filtered_period":
        return -math.expm1(-h / FILTER_TAU), bound
    return 0.0, 0.0


def compensation_factors(a: np.ndarray) -> np.ndarray:
    """The compensation mode's factors 1 + a in [0, 2] of actions a in [-1, 1] (a = 0 gives exactly 1)."""
    return 1.0 + a


def schedule_factors(a: np.ndarray) -> np.ndarray:
    """The schedule mode's factors (n, k) of actions a (n, k) in [-1, 1]: hi^a for a >= 0, lo^(-a) for a < 0, with
    (lo, hi) of :data:`SCHEDULE_RANGES` per column (a = 0 gives exactly 1)."""
    k = a.shape[1]
    # a * -log(lo) is -a * log(lo) to the bit (a product's sign is the XOR of its factors'): one product, not two
    return np.exp(a * np.where(a >= 0.0, _LOG_HI[:k], _NEG_LOG_LO[:k]))


# The residual's authority R of the rate and filtered modes and the reference mode's bound D, each twice the RMS of the
# ideal corrections on the unmodelled suite (32 episodes per task, the n = 2 law; ``python tools/action_authority.py``,
# docs/ENV.md "Action modes"), rounded up to one significant digit:
# - D: the shift d h y_d' that compensates the sensor delay d (1-2 samples): RMS 3.9e-4 rad/s (velocity), 1.25e-4 rad
#   (position). In position the oracle shift lowers the tracking RMSE 5x (8.7e-5 -> 1.75e-5 rad); in velocity the
#   quantisation dominates (x1.01).
# - R: the current that does the same, |d h y_d'| / k with k the error a 1 mA residual moves (9.5e-3 rad/s/mA, 7.2e-5
#   rad/mA: the law rejects most of it), plus the valve's ideal dead-band and hysteresis inverse th + h/2 (RMS 0.158
#   mA): RMS 0.179 mA (velocity), 1.82 mA (position).
CURRENT_AUTHORITY = (("velocity", 0.4), ("position", 4.0))
CURRENT_SOURCE = ("twice the RMS of the ideal current corrections on the unmodelled suite (delay compensation through "
                  "the law, dead-band and hysteresis inverse; tools/action_authority.py)")
SHIFT_BOUND = (("velocity", 8e-4), ("position", 3e-4))
SHIFT_SOURCE = ("twice the RMS of the delay-compensating shift d h y_d' on the unmodelled suite "
                "(tools/action_authority.py)")

ACTIONS: tuple[ActionMode, ...] = (
    ActionMode("current", "the residual current residual_scale * a [mA], held over the agent step", "", (),
               "residual_scale (the env's: the current limit)", "write_current"),
    ActionMode("rate", "the residual's rate of change a R / RATE_TIME [mA/s]; the residual, clipped to +-R, is "
               "integrated every control period", "mA", CURRENT_AUTHORITY, CURRENT_SOURCE, "write_held",
               period="rate_period"),
    ActionMode("filtered", "a first-order filter (time constant FILTER_TAU) of the residual R a [mA]", "mA",
               CURRENT_AUTHORITY, CURRENT_SOURCE, "write_held", period="filtered_period"),
    ActionMode("reference", "the law's reference shifted by D a [output unit] through a copy of the reference model",
               "U", SHIFT_BOUND, SHIFT_SOURCE, "write_reference", resense=True, shift=True),
    ActionMode("schedule", "the boundary layer's width, sigma and (observer on) its bandwidth scaled by factors "
               "within SCHEDULE_RANGES", "", (), "SCHEDULE_RANGES", "write_schedule", resense=True, dims=2,
               observer_dim=True, schedule=0),
    ActionMode("reference-schedule", "a_0 the reference mode's shift D a_0 [output unit], a_1 and a_2 the schedule "
               "mode's width and sigma factors", "U", SHIFT_BOUND, SHIFT_SOURCE, "write_reference_schedule",
               resense=True, dims=3, shift=True, schedule=1),
    ActionMode("compensation", "a_0 and a_1 scale the valve inverse and the reference delay by 1 + a in [0, 2], a_2 "
               "and a_3 are the schedule mode's width and sigma factors", "", (),
               "the loop's compensators (inverse_threshold, inverse_hysteresis, reference_delay)", "write_compensation",
               resense=True, dims=4, schedule=2, entries=("inverse", "delay", "width", "sigma"), compensators=True),
)
ACTION_NAMES = tuple(row.name for row in ACTIONS)

def action_mode(name: str) -> ActionMode:
    """The row of :data:`ACTIONS` named ``name``; ValueError naming the setting and the valid names otherwise."""
    for row in ACTIONS:
        if row.name == name:
            return row
    raise ValueError(f"action must be one of {list(ACTION_NAMES)}, got {name!r}")


def action_code(name: str) -> int:
    """The code (index in :data:`ACTIONS`) of mode ``name``."""
    return ACTIONS.index(action_mode(name))


def action_dims(mode: ActionMode, dob_hz: float) -> int:
    """The size k of ``mode``'s action (the schedule mode's: 2, width and sigma, or 3 with the observer on; the
    reference-schedule mode's 3; the compensation mode's 4)."""
    return mode.dims + (1 if mode.observer_dim and dob_hz > 0.0 else 0)


__all__ = ["ActionMode", "ACTIONS", "ACTION_NAMES", "RATE_TIME", "FILTER_TAU", "SCHEDULE_RANGES", "action_mode",
           "action_code", "action_dims", "period_constants", "schedule_factors", "compensation_factors"]
