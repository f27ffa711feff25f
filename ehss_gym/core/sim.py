"""The simulator: :func:`simulate` and :func:`simulate_batch` run closed-loop scenarios and return
:class:`Trajectory` records.

A :class:`~ehss_gym.core.settings.Scenario` holds every setting of a run. The loop is what a digital controller does
(:mod:`ehss_gym.core.controller`): sample, compute, hold the current for one control period (ZOH) while the plant is
integrated with RK4 substeps (:func:`ehss_gym.core.physics.integrate_lanes`). The reference model and the derivative
estimator are digital filters or, with an analog estimator, continuous filters integrated together with the plant
(``Scenario.estimator``: :data:`ehss_gym.core.registry.ESTIMATORS`). The scenarios of a batch that share a time grid
run in one compiled, parallel call (:func:`ehss_gym.core.loop.run_batch`); the metrics accumulate online at the full
control rate (:func:`ehss_gym.core.metrics.accumulate`), while the trajectory is logged every ``log_interval``.

A run that produces a non-finite value or leaves the state bounds (|x2| > ``omega_max``, |x3| > ``pressure_bound`` *
P_s) is stopped and reported as diverged with its time; its log ends at the last finite sample and no NaN is
returned.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numba as nb
import numpy as np

from .filters import filter_block
from .layout import (
    DIV_NAMES,
    DIV_NONE,
    EV_END,
    EV_START,
    L_DHAT,
    L_E,
    L_R,
    L_RM,
    L_S,
    L_T,
    L_TF,
    L_UAPP,
    L_UBASE,
    L_UCMD,
    L_UDOB,
    L_UMAX,
    L_UMIN,
    L_V,
    L_W,
    L_X,
    L_YD,
    L_YE,
    M_DIVERGED,
    M_LOST,
    M_T_DIVERGED,
    MAX_ORDER,
    N_FB,
    N_LOG,
    N_LOOP,
    N_METRICS,
)
from .loop import MAX_LANES, init_filters, run_batch, run_lanes
from .metrics import init_accumulator, summarize
from .references import reference_value
from .settings import PAPER_FRICTION, TASKS, UNITS, Scenario, ctrl_row, lambdas


def scenario_filter_block(sc: Scenario) -> np.ndarray:
    """The filter block of a scenario."""
    return filter_block(sc.order, sc.ref_model_hz, sc.estimator_hz, sc.control_period, sc.estimator, sc.observer_hz)


def initial_state(sc: Scenario, filt: np.ndarray | None = None) -> np.ndarray:
    """Plant at rest; reference model and estimator at their steady state for r(0) and y(0)."""
    z = np.zeros(N_LOOP)
    init_filters(z, scenario_filter_block(sc) if filt is None else filt, reference_value(0.0, sc.reference.spec))
    return z


def _stack_rows(rows: Sequence[np.ndarray]) -> np.ndarray:
    """Reference spec rows stacked, zero-padded to the longest (a table reference's row is longer)."""
    out = np.zeros((len(rows), max(len(r) for r in rows)))
    for i, r in enumerate(rows):
        out[i, :len(r)] = r
    return out


@dataclass
class LoopArrays:
    """Stacked per-scenario arrays for the kernels (one row per scenario)."""

    z0: np.ndarray
    plant: np.ndarray
    model: np.ndarray
    ctrl: np.ndarray
    ref: np.ndarray
    events: np.ndarray
    filt: np.ndarray

    @classmethod
    def build(cls, scenarios: Sequence[Scenario]) -> LoopArrays:
        h = scenarios[0].control_period
        n_ev = max(1, max(len(s.friction) for s in scenarios))
        events = np.zeros((len(scenarios), n_ev, 3))
        events[:, :, EV_START] = events[:, :, EV_END] = math.inf  # padding never fires
        for i, s in enumerate(scenarios):
            if s.friction:
                events[i, :len(s.friction)] = s.friction
        cache = {}
        filt = np.empty((len(scenarios), N_FB, MAX_ORDER, MAX_ORDER))
        for i, s in enumerate(scenarios):
            key = (s.order, s.ref_model_hz, s.estimator_hz, s.estimator, s.observer_hz)
            if key not in cache:
                cache[key] = filter_block(*key[:3], h, s.estimator, s.observer_hz)
            filt[i] = cache[key]
        return cls(
            z0=np.stack([initial_state(s, f) for s, f in zip(scenarios, filt)]),
            plant=np.stack([s.plant.as_array() for s in scenarios]),
            model=np.stack([(s.model or s.plant).as_array() for s in scenarios]),
            ctrl=np.stack([ctrl_row(s) for s in scenarios]),
            ref=_stack_rows([s.reference.spec for s in scenarios]),
            events=events,
            filt=filt,
        )


@dataclass
class Trajectory:
    """A simulated run: logged signals plus metrics accumulated at the control rate.

    Signals are logged every ``scenario.log_interval`` (the sample at t_k holds
    the state at t_k and what the controller did then). Units: t [s], y, y_ref,
    e in the output unit (rad/s velocity, rad position), u [mA], friction [N*m].
    """

    scenario: Scenario
    log: np.ndarray = field(repr=False)
    acc: np.ndarray = field(repr=False)

    t = property(lambda self: self.log[:, L_T])
    x = property(lambda self: self.log[:, L_X:L_X + 4], doc="plant states (x1..x4)")
    r = property(lambda self: self.log[:, L_R], doc="reference-model input r")
    s = property(lambda self: self.log[:, L_S], doc="combined error")
    V = property(lambda self: self.log[:, L_V], doc="CLF value")
    u = property(lambda self: self.log[:, L_UCMD], doc="commanded current [mA]")
    u_applied = property(lambda self: self.log[:, L_UAPP], doc="applied current [mA]")
    u_base = property(lambda self: self.log[:, L_UBASE], doc="base current [mA]: the law's plus the observer's")
    u_dob = property(lambda self: self.log[:, L_UDOB], doc="the disturbance observer's current [mA] (0 if off)")
    d_hat = property(lambda self: self.log[:, L_DHAT],
                     doc="the disturbance observer's estimate of d in s' = psi + G u + d [unit of s / s] (0 if off)")
    friction = property(lambda self: self.log[:, L_TF], doc="friction torque [N*m]")
    u_applied_min = property(lambda self: self.log[:, L_UMIN],
                             doc="smallest applied current over each sample's log interval [mA]")
    u_applied_max = property(lambda self: self.log[:, L_UMAX],
                             doc="largest applied current over each sample's log interval [mA]")
    width = property(lambda self: self.log[:, L_W], doc="boundary-layer width in use [unit of s]")
    r_model = property(lambda self: self.log[:, L_RM], doc="the reference model's input (r, or the shaped r)")
    e = property(lambda self: self.log[:, L_E], doc="tracking error y - y_d")

    @property
    def y(self):
        """Plant output: x2 (velocity) or x1 (position)."""
        return self.x[:, 1 if self.scenario.task == "velocity" else 0]

    @property
    def y_ref(self):
        """Reference-model output y_d."""
        return self.log[:, L_YD]

    @property
    def y_ref_derivs(self):
        """y_d, y_d', ..., y_d^(m) (m+1 columns)."""
        return self.log[:, L_YD:L_YD + self.scenario.order + 1]

    @property
    def y_est_derivs(self):
        """Measured y and the estimated y', ..., y^(m-1) (m columns)."""
        return self.log[:, L_YE:L_YE + self.scenario.order]

    @property
    def diverged(self) -> bool:
        return self.acc[M_DIVERGED] != DIV_NONE

    @property
    def divergence_reason(self) -> str:
        return DIV_NAMES[int(self.acc[M_DIVERGED])]

    @property
    def t_diverged(self) -> float | None:
        return float(self.acc[M_T_DIVERGED]) if self.diverged else None

    @property
    def lost_track(self) -> bool:
        """The windowed RMS of e exceeded the scenario's lost-track bound (see :class:`Scenario`)."""
        return bool(self.acc[M_LOST] > 0.0)

    def metrics(self) -> dict:
        """Summary metrics; see :func:`ehss_gym.core.metrics.summarize`."""
        return summarize(self)

    def units(self) -> dict[str, str]:
        """The unit of each of :meth:`arrays` (U = rad/s velocity, rad position; "-" = dimensionless)."""
        U = UNITS[self.scenario.task]
        m = self.scenario.order
        lift = 1 if self.scenario.task == "velocity" else 0  # U = rad/s^lift

        def deriv(i: int) -> str:  # the unit of the i-th time derivative of the output
            p = i + lift
            return "rad" if p == 0 else ("rad/s" if p == 1 else f"rad/s^{p}")

        out = {"t": "s", "y": U, "y_ref": U, "e": U, "u": "mA", "u_applied": "mA", "u_base": "mA",
               "s": deriv(m - 1), "V": "-", "friction": "N*m", "r": U, "u_applied_min": "mA",
               "u_applied_max": "mA", "u_dob": "mA", "d_hat": deriv(m), "theta": "rad", "omega": "rad/s",
               "p_load": "Pa", "valve_area": "m^2"}
        for i in range(1, m + 1):
            out[f"y_ref_d{i}"] = deriv(i)
        for i in range(1, m):
            out[f"y_est_d{i}"] = deriv(i)
        return out

    def arrays(self) -> dict[str, np.ndarray]:
        """Named arrays for saving (npz / csv)."""
        out = {"t": self.t, "y": self.y, "y_ref": self.y_ref, "e": self.e, "u": self.u, "u_applied": self.u_applied,
               "u_base": self.u_base, "s": self.s, "V": self.V, "friction": self.friction, "r": self.r,
               "u_applied_min": self.u_applied_min, "u_applied_max": self.u_applied_max, "u_dob": self.u_dob,
               "d_hat": self.d_hat}
        names = ("theta", "omega", "p_load", "valve_area")
        for i, nm in enumerate(names):
            out[nm] = self.x[:, i]
        for i in range(1, self.scenario.order + 1):
            out[f"y_ref_d{i}"] = self.y_ref_derivs[:, i]
        for i in range(1, self.scenario.order):
            out[f"y_est_d{i}"] = self.y_est_derivs[:, i]
        return out


def simulate_batch(scenarios: Sequence[Scenario]) -> list[Trajectory]:
    """Simulate many scenarios; those sharing a time grid run in one compiled parallel call."""
    scenarios = list(scenarios)
    if not scenarios:
        return []
    for i, s in enumerate(scenarios):
        if not isinstance(s, Scenario):
            raise ValueError(f"scenarios[{i}] must be a Scenario, got {type(s).__name__}")
    groups: dict[tuple, list[int]] = {}
    for i, s in enumerate(scenarios):
        groups.setdefault(s.grid(), []).append(i)
    out: list[Trajectory | None] = [None] * len(scenarios)
    for (h, substeps, n_steps, log_every), idx in groups.items():
        group = [scenarios[i] for i in idx]
        a = LoopArrays.build(group)
        n_rows = (n_steps + log_every - 1) // log_every
        log = np.zeros((len(group), n_rows, N_LOG))
        acc = np.zeros((len(group), N_METRICS))
        n_log = np.zeros(len(group), dtype=np.int64)
        for j, s in enumerate(group):
            init_accumulator(acc[j], s.lost_track_bound)
        z = a.z0.copy()
        if len(group) == 1:  # skip the thread pool for a single run
            run_lanes(z, h, substeps, n_steps, log_every, a.plant, a.model, a.ctrl, a.ref, a.events, a.filt, log,
                      acc, n_log)
        else:
            threads = max(1, min(nb.get_num_threads(), len(group)))
            chunk = min(MAX_LANES, -(-len(group) // threads))
            run_batch(z, h, substeps, n_steps, log_every, a.plant, a.model, a.ctrl, a.ref, a.events, a.filt, log,
                      acc, n_log, chunk)
        for j, i in enumerate(idx):  # views, not copies: peak memory stays ~1x the trajectory data
            out[i] = Trajectory(group[j], log[j, :n_log[j]], acc[j])
    return out


def simulate(scenario: Scenario | None = None, **changes) -> Trajectory:
    """Simulate one scenario (default: the paper's velocity run, f_r = 100 Hz, n = 2).

    Keyword arguments change fields of ``scenario``; see :class:`Scenario`.
    """
    sc = scenario or Scenario()
    if changes:
        sc = sc.replace(**changes)
    return simulate_batch([sc])[0]


__all__ = ["Scenario", "Trajectory", "simulate", "simulate_batch", "LoopArrays", "initial_state", "filter_block",
           "scenario_filter_block", "ctrl_row", "lambdas", "PAPER_FRICTION", "TASKS", "UNITS", "MAX_LANES"]
