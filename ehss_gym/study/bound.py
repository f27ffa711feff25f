r"""The physical bound of a step: the least IAE any policy can reach under the current limit.

A step of the reference r(t) = A [t >= t_step] from rest (x = 0) is answered by some current profile u(t) with
|u| <= the current limit, whatever policy makes it (a CLF law, a PID loop, a learned agent). The bound is

    IAE* = min over |u(t)| <= u_max of  integral_{t_step}^{t_end} |y(t) - A| dt

on the true plant (Eq. (1), :mod:`ehss_gym.core.physics`; y = x2 for the velocity task, x1 for the position
task). Every causal policy applies one admissible profile; the minimum over all of them knows the reference and
the plant in advance and so can do no worse: a policy whose IAE is below IAE* would prove the bound wrong. The
ratio IAE / IAE* of a policy is how far it is from what the valve allows.

**How it is computed.** Direct single shooting: u is piecewise constant on a control grid (``grid`` [s]) over a
window after the step and held at the steady current of the target after it; the plant is integrated by the
simulator's RK4 at the simulator's step (the same compiled right-hand side, bit for bit,
:mod:`ehss_gym.study.bound_kernels`). The IAE is minimised exactly, without smoothing, by sequential linear
programming: at each iterate the output's sensitivities to every current value (forward sensitivities of the
RK4 map, exact for the discretised plant) turn the IAE into a linear program in the step du, solved with HiGHS
inside a trust region |du| <= Delta; a step is kept when the true IAE falls by at least a tenth of what the
linear model promised, and Delta grows or shrinks with that ratio. A gradient method on a smoothed IAE
(sqrt(e^2 + eps^2), L-BFGS-B) stalls here: the hold after the target asks for a current within ~0.01 mA of the
steady one while the bounds are +-10 mA, so it needs thousands of iterations and still ends a few per cent
above; the exact L1 program finds the bang-bang profile in a few dozen.

**Its numerical gap.** A numerical optimum of a non-convex problem is an *upper* estimate of the true minimum
(it is the IAE of a profile that exists, so the true minimum is at most this; it could be lower). How much lower
is estimated three ways, all in :class:`StepBound`'s diagnostics:

(a) several starts (u = +limit and -limit over the window, zero, a bang-then-hold guess, uniform random) are
    optimised separately; their spread is reported (``start_spread``);
(b) the best profile is refined on a control grid twice as fine; the change is reported (``refinement``) and the
    lower of the two is the bound;
(c) Pontryagin's necessary condition: the Hamiltonian is linear in u, so the optimal current is at +-limit
    wherever the switching function is away from zero: ``saturated_share`` is the share of the control
    intervals before the target is first reached that sit at +-limit. ``stationarity`` is what the linearised
    IAE could still gain by moving every current by 0.1 mA.

The horizon must be long enough that nothing after the window matters: ``tail_share`` is the share of the IAE
accrued after the window (the plant held at the target by the steady current), and the window is doubled until
it is below 1e-3. The profile's IAE is recomputed exactly (trapezoid rule on the integrator's step) over
[t_step, t_end].

The bound is over policies that hold the plant at rest until the step: a policy told the step time in advance
could open the valve early and do better; none of the env's policies can.
"""

from __future__ import annotations

import argparse
import csv
import functools
import math
import pathlib
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from matplotlib.figure import Figure
from scipy.optimize import brentq, linprog

from ehss_gym.core.layout import X_AV, X_OMEGA, X_PL, X_THETA
from ehss_gym.core.params import P_K, PlantParams
from ehss_gym.core.physics import active_amplitude
from ehss_gym.core.settings import check_friction
from ehss_gym.core.signals import step
from ehss_gym.core.sim import TASKS, UNITS, simulate
from ehss_gym.core.validate import check_finite, check_int, check_positive
from ehss_gym.envs.config import DEFAULTS, EnvConfig
from ehss_gym.infra.fmt import fmt_cell, md_table

from . import bound_kernels

SIM_STEP = DEFAULTS.control_period / DEFAULTS.substeps  # [s] the env's RK4 step: the bound's integrator step
DEFAULT_GRID = {"velocity": 2e-4, "position": 1e-3}  # [s] control grid per task (refined to half of it)
WINDOW_FACTOR = 3.0  # the first window: this many times the full-open crossing time (doubled as needed)
HOLD = 0.1  # [s] of held steady current after the window, inside the optimised objective
TAIL_TOL = 1e-3  # largest share of the IAE accrued after the window
STATIONARITY_MOVE = 0.01  # the trust region of the stationarity check, as a share of the current limit
# grid levels per start (4, 2 and 1 times the control grid for 3): the position task's starts crawl on one grid;
# the velocity task's converge on one in fewer programs than a cascade takes
CASCADE = {"velocity": 1, "position": 3}
STATIONARY_TOL = 1e-4  # a start has converged when its stationarity measure is below this
START_TOL = 1e-3  # largest accepted spread of the starts' IAEs (relative)
REFINE_TOL = 1e-3  # largest accepted gain of halving the control grid (relative)
SWITCHING_MIN = 0.9  # least share of the decisive intervals before the target at the limit their sign asks for
START_NAMES = ("bang-hold", "zero", "plus", "minus", "random")
OUTPUT = {"velocity": X_OMEGA, "position": X_THETA}
# HiGHS's dual simplex, then its interior-point method: the simplex is the faster, but on some position-task
# programs (a closed valve, sensitivities spread over 7 decades) it ends with status "unknown"
LP_METHODS = ("highs-ds", "highs-ipm")


@dataclass(frozen=True, eq=False)
class Model:
    """A model for the optimiser core.

    Attributes:
        kind: its code in :mod:`ehss_gym.study.bound_kernels` (``MODEL_EHSS``, ``MODEL_LAG``).
        p: its parameter array.
        n: state size.
        out: index of the output y in the state.
        clip: index of a state projected onto [-clip_value, clip_value] after each step (-1: none).
        clip_value: that bound.
    """

    kind: int
    p: np.ndarray
    n: int
    out: int
    clip: int = -1
    clip_value: float = 0.0


def plant_model(task: str, plant: PlantParams) -> Model:
    """The EHSS plant of Eq. (1) with its relief valves, output x2 (velocity) or x1 (position)."""
    return Model(bound_kernels.MODEL_EHSS, plant.as_array(), 4, OUTPUT[task], X_PL, float(plant.P_s))


def lag_model(gain: float, time_constant: float) -> Model:
    """The first-order lag y' = (k u - y) / T (k = ``gain``, T = ``time_constant`` [s]): the closed-form case."""
    return Model(bound_kernels.MODEL_LAG, np.array([gain, time_constant], dtype=np.float64), 1, 0)


@dataclass(frozen=True, eq=False)
class Problem:
    """min IAE of y - target over piecewise-constant u, |u| <= limit, from x0.

    Attributes:
        model: the dynamics.
        x0: initial state.
        dt: integrator step [s].
        amps: per step, the scalar ``a`` passed to the model (friction amplitude at the step's midpoint).
        idx: per step, the index of its control value; -1 = the held current ``u_hold``.
        n_ctrl: number of control values.
        target: the output's target.
        limit: the bound on |u|.
        u_hold: the current held after the window.
        spc: integrator steps per control interval.
        rows: the steps whose errors form the linear programs' objective (every ``row_every`` steps, and the last).
        row_every: a divisor of ``spc``.
    """

    model: Model
    x0: np.ndarray
    dt: float
    amps: np.ndarray
    idx: np.ndarray
    n_ctrl: int
    target: float
    limit: float
    u_hold: float
    spc: int
    rows: np.ndarray = field(repr=False)
    row_every: int = 1

    @property
    def n_steps(self) -> int:
        return int(self.amps.shape[0])

    def weights(self) -> np.ndarray:
        """Trapezoid weights [s] of the n_steps + 1 samples."""
        w = np.full(self.n_steps + 1, self.dt)
        w[0] = w[-1] = 0.5 * self.dt
        return w

    def simulate(self, u) -> np.ndarray:
        """States (n_steps + 1, n) of profile ``u``; RuntimeError if they leave the finite numbers."""
        X = np.zeros((self.n_steps + 1, self.model.n))
        m = self.model
        done = bound_kernels.simulate_profile(np.asarray(u, dtype=np.float64), self.idx, self.u_hold, self.x0,
                                              self.dt, m.p, self.amps, m.kind, m.clip, m.clip_value, X,
                                              np.zeros(self.n_steps, np.bool_))
        if done < self.n_steps:
            raise RuntimeError(f"the plant left the finite numbers at step {done} of {self.n_steps}")
        return X

    def iae(self, u) -> float:
        """The exact (trapezoid) IAE of ``u`` [output unit * s]."""
        return float(np.sum(self.weights() * np.abs(self.simulate(u)[:, self.model.out] - self.target)))

    def sensitivity(self, u) -> tuple[np.ndarray, np.ndarray]:
        """(X, S): the states and S[r, j] = d y / d u_j at the sample rows[r]."""
        m = self.model
        X = np.zeros((self.n_steps + 1, m.n))
        S = np.zeros((len(self.rows), self.n_ctrl))
        done = bound_kernels.output_sensitivity(np.asarray(u, dtype=np.float64), self.idx, self.row_every, self.u_hold,
                                    self.x0, self.dt, m.p, self.amps, m.kind, m.clip, m.clip_value, m.out, X,
                                    np.zeros(self.n_steps, np.bool_), S)
        if done < self.n_steps:
            raise RuntimeError(f"the plant left the finite numbers at step {done} of {self.n_steps}")
        return X, S


def make_problem(model: Model, *, target: float, limit: float, u_hold: float, dt: float, spc: int, n_ctrl: int,
                 n_steps: int, amps=None, x0=None, row_every: int | None = None) -> Problem:
    """A problem with ``n_ctrl`` control intervals of ``spc`` integrator steps, then ``u_hold`` up to
    ``n_steps``; the linear programs sample the error every ``row_every`` steps (a divisor of ``spc``; default
    ``spc``: sampling every step changes the optimum by less than the grid does, and costs much more)."""
    idx = np.full(n_steps, -1, dtype=np.int64)
    m = min(n_steps, n_ctrl * spc)
    idx[:m] = np.arange(m) // spc
    row_every = spc if row_every is None else row_every
    rows = np.arange(0, n_steps + 1, row_every)
    if rows[-1] != n_steps:
        rows = np.append(rows, n_steps)
    return Problem(model, np.zeros(model.n) if x0 is None else np.asarray(x0, dtype=np.float64), float(dt),
                   np.zeros(n_steps) if amps is None else np.asarray(amps, dtype=np.float64), idx, int(n_ctrl),
                   float(target), float(limit), float(u_hold), int(spc), rows, int(row_every))


@dataclass(frozen=True, eq=False)
class Solution:
    """One optimiser run: the profile, its exact IAE, the iterations taken and the final trust radius."""

    u: np.ndarray
    iae: float
    iterations: int
    radius: float


def _row_weights(problem: Problem) -> np.ndarray:
    """Trapezoid weights [s] on the sample rows of the linear programs."""
    t = problem.rows * problem.dt
    w = np.zeros(len(t))
    d = np.diff(t)
    w[:-1] += 0.5 * d
    w[1:] += 0.5 * d
    return w


def linear_step(problem: Problem, u: np.ndarray, radius: float) -> tuple[np.ndarray, float, float, np.ndarray]:
    """The step du within |du| <= radius * limit (and the bounds) that minimises the linearised IAE.

    Returns (du, the linear model's IAE at du = 0, its IAE at du, both on the row quadrature [output unit * s],
    and the reduced costs of du: d IAE / d u_j with the subgradient of |e| at e = 0 the program's multipliers
    pick, the switching function of Pontryagin's principle [scaled, only signs and ratios mean anything]).
    """
    X, S = problem.sensitivity(u)
    scale = abs(problem.target) or 1.0
    e0 = (X[problem.rows, problem.model.out] - problem.target) / scale
    Sr = S * (problem.limit / scale)
    n, nc = len(e0), problem.n_ctrl
    c_rows = _row_weights(problem) * 1e3  # [ms]: the program's numbers stay near 1
    A_eq = sp.hstack([sp.csr_matrix(Sr), sp.identity(n, format="csr") * -1.0, sp.identity(n, format="csr")],
                     format="csc")
    v = u / problem.limit
    lo = np.concatenate([np.maximum(-1.0 - v, -radius), np.zeros(2 * n)])
    hi = np.concatenate([np.minimum(1.0 - v, radius), np.full(2 * n, np.inf)])
    cost = np.concatenate([np.zeros(nc), c_rows, c_rows])
    for method in LP_METHODS:
        res = linprog(cost, A_eq=A_eq, b_eq=-e0, bounds=np.column_stack([lo, hi]), method=method)
        if res.status == 0:
            break
    else:
        raise RuntimeError(f"the linear program failed: {res.message}")
    f0 = math.fsum(c_rows * np.abs(e0)) * scale * 1e-3  # correctly rounded: not BLAS's CPU-dependent order
    sigma = res.lower.marginals[:nc] + res.upper.marginals[:nc]
    return res.x[:nc] * problem.limit, f0, float(res.fun) * scale * 1e-3, sigma


def minimise_iae(problem: Problem, u0, *, max_iter: int = 60, radius: float = 0.2, tol: float = 1e-6,
                 stall: float = 1e-5) -> Solution:
    """Sequential linear programming with a trust region on the exact IAE, from profile ``u0``.

    Stops when the linear model promises less than ``tol`` of the IAE, when the last ten programs lowered it by
    less than ``stall`` of itself in all, when the radius falls below 1e-7 of the limit, or after ``max_iter``
    programs.
    """
    u = np.clip(np.asarray(u0, dtype=np.float64), -problem.limit, problem.limit)
    f = problem.iae(u)
    history = [f]
    it = 0
    while it < max_iter:
        it += 1
        du, m0, m1, _ = linear_step(problem, u, radius)
        predicted = m0 - m1
        if predicted <= tol * f:
            break
        trial = np.clip(u + du, -problem.limit, problem.limit)
        try:
            ft = problem.iae(trial)
        except RuntimeError:  # a step that blows the plant up is a rejected step
            ft = math.inf
        rho = (f - ft) / predicted
        if rho > 0.1:
            u, f = trial, ft
        if rho < 0.25:
            radius *= 0.3
        elif rho > 0.75 and np.max(np.abs(du)) > 0.99 * radius * problem.limit:
            radius = min(2.0 * radius, 2.0)
        history.append(f)
        if radius < 1e-7 or (len(history) > 10 and history[-11] - f < stall * f):
            break
    return Solution(u, f, it, radius)


def first_order_check(problem: Problem, u, t_reach: float) -> tuple[float, float, float]:
    """The necessary conditions at a profile ``u``, from one linear program with |du| <= 1 % of the limit.

    Returns:
        stationarity: what the linearised IAE could still gain in that region, as a share of the IAE (~0 at a
            first-order stationary profile).
        saturated_share: share of the control intervals that end before ``t_reach`` [s] at +-limit.
        switching_share: Pontryagin's condition over those intervals whose switching function sigma_j (the
            program's reduced cost of u_j) is away from zero (above 1 % of its largest magnitude there): the share
            that sit at the limit -sign(sigma_j) asks for. NaN where no interval qualifies.
    """
    u = np.asarray(u, dtype=np.float64)
    _, m0, m1, sigma = linear_step(problem, u, STATIONARITY_MOVE)
    ends = (np.arange(problem.n_ctrl) + 1) * problem.spc * problem.dt
    pre = ends <= t_reach if math.isfinite(t_reach) else np.ones(problem.n_ctrl, dtype=bool)
    at_limit = np.abs(u) >= problem.limit * (1.0 - 1e-6)
    decisive = pre & (np.abs(sigma) > 0.01 * np.max(np.abs(sigma[pre]), initial=0.0))
    right = at_limit & (np.sign(u) == -np.sign(sigma))
    return (max(0.0, m0 - m1) / max(m0, 1e-300), float(np.mean(at_limit[pre])) if pre.any() else math.nan,
            float(np.mean(right[decisive])) if decisive.any() else math.nan)


# --- The bound of a step on the EHSS plant ---------------------------------------------------------------------


@dataclass(frozen=True)
class BoundDiagnostics:
    """How far the numerical bound may be from the true minimum, and what the optimiser did.

    Attributes:
        iae_by_start: (start name, the IAE it converged to [output unit * s], its stationarity [-]) on the
            control grid (twice ``StepBound.grid``).
        start_spread: (largest - smallest) / smallest of the IAEs of the starts that reached a stationary profile
            (stationarity <= ``STATIONARY_TOL``) [-]; NaN if none did.
        n_stationary: how many starts did.
        iae_coarse: the best IAE on the control grid ``grid`` [output unit * s].
        iae_fine: the IAE on a grid half as fine, started from the best coarse profile [output unit * s].
        refinement: (iae_coarse - iae_fine) / iae_fine [-]: what halving the grid gained.
        iterations: linear programs solved, per start and for the refinement, in all.
        stationarity: what the linearised IAE could still gain by moving every current by 1 % of the limit, as a
            share of the IAE [-] (0 at a first-order stationary profile; the nonsmooth counterpart of a gradient
            norm).
        saturated_share: share of the control intervals before the target is first reached at +-limit [-].
        switching_share: the same over the intervals whose switching function (d IAE / d u) is away from zero
            (above 1 % of its largest magnitude), counting only those at the limit its sign asks for [-].
        tail_share: share of the IAE accrued after the optimised window, with the steady current held [-].
        window: the optimised window after the step [s].
        wall_time: seconds the computation took (a cached result keeps the time of its first computation) [s].
    """

    iae_by_start: tuple
    start_spread: float
    n_stationary: int
    iae_coarse: float
    iae_fine: float
    refinement: float
    iterations: int
    stationarity: float
    saturated_share: float
    switching_share: float
    tail_share: float
    window: float
    wall_time: float

    def checks(self) -> dict[str, bool]:
        """Each gap estimate against its stated tolerance (module constants)."""
        agree = self.start_spread <= START_TOL and 2 * self.n_stationary > len(self.iae_by_start)
        return {"starts agree": agree, "grid refined": self.refinement <= REFINE_TOL,
                "bang-bang": self.switching_share >= SWITCHING_MIN, "tail": self.tail_share <= TAIL_TOL}


@dataclass(frozen=True, eq=False)
class StepBound:
    """The least IAE of a step from rest under the current limit, with the profile that reaches it.

    Attributes:
        task: "velocity" (y = x2 [rad/s]) or "position" (y = x1 [rad]).
        amplitude: the step's size [output unit].
        t_step: the step's time [s].
        t_end: end of the IAE's window [s].
        current_limit: the bound on |u| [mA].
        iae_bound: min IAE of y - r over [t_step, t_end] [output unit * s] (an upper estimate of the true minimum,
            see the module's notes and ``diagnostics``).
        t: the integrator's time grid over [t_step, t_end] [s].
        y: the output of the optimal profile on ``t`` [output unit].
        u: the optimal current on ``t`` [mA] (held over each step; the last value repeated).
        x: the plant's states on ``t`` (x1 [rad], x2 [rad/s], x3 [Pa], x4 [m^2]).
        grid: the control grid of the profile [s].
        u_hold: the steady current that holds the target [mA].
        t_reach: time from the step until y first reaches the target [s] (NaN if it never does).
        t_reach_open: time from the step until y first reaches the target with u = +limit throughout (toward the
            target): a lower bound on any profile's ``t_reach`` [s].
        iae_bang_hold: IAE of u = +limit until that crossing, then ``u_hold`` [output unit * s].
        diagnostics: the numerical gap and the optimiser's record.
    """

    task: str
    amplitude: float
    t_step: float
    t_end: float
    current_limit: float
    iae_bound: float
    t: np.ndarray = field(repr=False)
    y: np.ndarray = field(repr=False)
    u: np.ndarray = field(repr=False)
    x: np.ndarray = field(repr=False)
    grid: float
    u_hold: float
    t_reach: float
    t_reach_open: float
    iae_bang_hold: float
    diagnostics: BoundDiagnostics

    @property
    def unit(self) -> str:
        """The output's unit."""
        return UNITS[self.task]

    def ratio(self, iae: float) -> float:
        """A policy's IAE over the bound [-] (>= 1 for every policy, if the bound holds)."""
        return float(iae) / self.iae_bound

    def figure_data(self) -> dict[str, np.ndarray]:
        """t [s], r, y [output unit] and u [mA] of the optimal profile, for a figure or a CSV."""
        return {"t": self.t, "r": np.full_like(self.t, self.amplitude), "y": self.y, "u": self.u}

    def plot(self, path=None, *, law=None, made_by: str | None = None):
        """Figure of y(t) and u(t) of the optimal profile, and of a run's (``law``: a Trajectory) if given.

        Saves to ``path`` (PNG) and returns the path, or returns the matplotlib figure if ``path`` is None.
        """
        return bound_figure([self], [law] if law is not None else None, path, made_by=made_by)


def step_bound(task: str, amplitude: float, *, t_step: float, t_end: float, plant: PlantParams | None = None,
               current_limit: float = 10.0, friction: tuple = (), grid: float | None = None, dt: float = SIM_STEP,
               window: float | None = None, starts: tuple = START_NAMES, seed: int = 0,
               max_iter: int = 60) -> StepBound:
    """The least IAE of a step of the reference from rest under the current limit (see the module's notes).

    Results are cached per argument set, so a suite asking again for the same step pays nothing.

    Args:
        task: "velocity" (y = x2) or "position" (y = x1).
        amplitude: the step's size A != 0 [output unit: rad/s velocity, rad position]; a velocity step must be
            one the current limit can hold.
        t_step: the step's time [s], >= 0; the plant is at rest (x = 0) until then.
        t_end: end of the IAE's window [s], > t_step, long enough for the window and the hold.
        plant: true plant parameters (default Table I).
        current_limit: the bound on |u| [mA], > 0.
        friction: Coulomb friction events (amplitude [N*m], start [s], end [s]), as in Scenario.friction.
        grid: control grid [s], an even multiple of ``dt`` (default 0.2 ms velocity, 1 ms position).
        dt: the integrator's (RK4) step [s] (default the env's: its control period over its substeps).
        window: optimised window after the step [s] (default three times the full-open crossing time, doubled
            until the IAE after it is below ``TAIL_TOL`` of the total).
        starts: names of the starting profiles, a non-empty subset of ``START_NAMES``.
        seed: seed of the "random" start.
        max_iter: most linear programs per start.

    Raises:
        ValueError: a parameter out of its range (named in the message), a velocity the limit cannot hold, a
            target not reached within t_end, or a horizon too short for the window.
    """
    key = bound_inputs(task, amplitude, t_step, t_end, plant, current_limit, friction, grid, dt, window, starts, seed,
                     max_iter)
    return _cached_bound(key)


def bound_inputs(task, amplitude, t_step, t_end, plant, current_limit, friction, grid, dt, window, starts, seed,
               max_iter) -> tuple:
    """The arguments of :func:`step_bound` checked and with their defaults resolved, as one hashable tuple: every
    input a bound depends on (what :mod:`ehss_gym.study.bound_table` keys its kept bounds by)."""
    if task not in TASKS:
        raise ValueError(f"task must be one of {sorted(TASKS)}, got {task!r}")
    amplitude = check_finite("amplitude", amplitude)
    if amplitude == 0.0:
        raise ValueError("amplitude must be a finite number other than 0 [output unit], got 0")
    t_step = check_finite("t_step", t_step, low=0.0)
    t_end = check_finite("t_end", t_end, low=t_step, low_open=True)
    plant = PlantParams() if plant is None else plant
    if not isinstance(plant, PlantParams):
        raise ValueError(f"plant must be a PlantParams (use make_plant_params), got {type(plant).__name__}")
    current_limit = check_positive("current_limit", current_limit)
    friction = check_friction(friction)
    dt = check_finite("dt", dt, low=0.0, high=1e-3, low_open=True)
    grid = DEFAULT_GRID[task] if grid is None else check_positive("grid", grid)
    spc = grid / dt
    if abs(spc - round(spc)) > 1e-9 * spc or round(spc) < 2 or round(spc) % 2:
        raise ValueError(f"grid must be an even multiple (>= 2) of dt = {dt:g} s, got {grid:g} s")
    if window is not None:
        window = check_finite("window", window, low=grid, high=t_end - t_step)
    if isinstance(starts, str) or not starts or any(s not in START_NAMES for s in starts):
        raise ValueError(f"starts must be a non-empty tuple of names from {list(START_NAMES)}, got {starts!r}")
    seed = check_int("seed", seed, 0)
    max_iter = check_int("max_iter", max_iter, 1)
    return (task, amplitude, t_step, t_end, plant, current_limit, friction, float(grid), dt, window,
            tuple(dict.fromkeys(starts)), seed, max_iter)


@functools.lru_cache(maxsize=128)
def _cached_bound(key: tuple) -> StepBound:
    return _solve(*key)


def hold_current(task: str, amplitude: float, model: Model, current_limit: float, a_end: float = 0.0) -> float:
    """The steady current [mA] that holds the plant at the target: velocity, the equilibrium with x2 = A (found
    on Eq. (1) itself: x3 from x2' = 0, x4 from x3' = 0, u from x4' = 0); position, 0 (at rest at x1 = A the
    valve is closed). ``a_end`` is the friction amplitude active at the end [N*m].

    Raises:
        ValueError: the velocity needs |x3| > P_s or |u| > the current limit.
    """
    if task == "position":
        return 0.0
    p = model.p
    x = np.array([0.0, amplitude, 0.0, 0.0])

    def rate(i: int, j: int, v: float, u: float = 0.0) -> float:
        x[j] = v
        dx = np.zeros(4)
        bound_kernels.ehss_rhs(x, u, a_end, p, dx)
        return float(dx[i])

    ps = model.clip_value
    x4_max = p[P_K] * current_limit  # K u_max [m^2]
    unholdable = ValueError(f"amplitude {amplitude:g} rad/s cannot be held with |u| <= current_limit = "
                            f"{current_limit:g} mA on this plant: choose a smaller step")
    if rate(X_OMEGA, X_PL, -ps) * rate(X_OMEGA, X_PL, ps) > 0.0:
        raise unholdable
    x[X_PL] = brentq(lambda v: rate(X_OMEGA, X_PL, v), -ps, ps, xtol=1e-9, rtol=1e-14)
    if rate(X_PL, X_AV, -x4_max) * rate(X_PL, X_AV, x4_max) > 0.0:
        raise unholdable
    x[X_AV] = brentq(lambda v: rate(X_PL, X_AV, v), -x4_max, x4_max, xtol=1e-22, rtol=1e-14)
    return float(brentq(lambda v: rate(X_AV, X_AV, x[X_AV], v), -current_limit, current_limit, xtol=1e-14))


def _amplitudes(friction: tuple, t0: float, dt: float, n: int) -> np.ndarray:
    """The friction amplitude at each step's midpoint [N*m], as the simulator takes it."""
    ev = np.array(friction, dtype=np.float64).reshape(-1, 3)
    return np.array([active_amplitude(t0 + (s + 0.5) * dt, ev) for s in range(n)])


def crossing_time(y: np.ndarray, target: float, dt: float) -> float:
    """First time y reaches ``target`` from its start (linear interpolation) [s after the first sample]; NaN if
    never."""
    d = np.sign(target) * (np.asarray(y) - target)
    hit = np.flatnonzero(d >= 0.0)
    if not hit.size:
        return math.nan
    i = int(hit[0])
    return 0.0 if i == 0 else float((i - 1 + d[i - 1] / (d[i - 1] - d[i])) * dt)


def start_profile(name: str, problem: Problem, t_open: float, seed: int) -> np.ndarray:
    """A starting profile on the problem's control grid [mA]: "bang-hold" (+limit toward the target until the
    full-open crossing time ``t_open`` [s], then the held current), "zero", "plus", "minus" (+-limit throughout)
    or "random" (uniform in +-limit)."""
    nc, lim = problem.n_ctrl, problem.limit
    if name == "bang-hold":
        t_start = np.arange(nc) * problem.spc * problem.dt
        return np.where(t_start < t_open, math.copysign(lim, problem.target), problem.u_hold)
    if name == "random":
        return np.random.default_rng(seed).uniform(-lim, lim, nc)
    return np.full(nc, {"zero": 0.0, "plus": lim, "minus": -lim}[name])


@dataclass(frozen=True, eq=False)
class _Window:
    """One optimised window: every start's result, the refined profile and its full-horizon trajectory."""

    starts: dict  # name -> (Solution on the control grid, its stationarity)
    fine_problem: Problem
    fine: Solution
    X: np.ndarray
    idx: np.ndarray
    iae: float
    tail_share: float
    n_window: int


def cascade(make, u0, top: int, spc: int, max_iter: int) -> Solution:
    """Minimise on grids of ``top``, ``top/2``, ..., ``spc`` integrator steps (``make(s)`` builds the problem on
    intervals of s steps), each started from the last one's profile: the coarse grids find the switching
    structure in few variables, so the fine grid only polishes (the linear programs' steps cannot follow a
    curved valley, and a fine grid from a poor start crawls along it)."""
    s, u, its = top, np.asarray(u0, dtype=np.float64), 0
    while True:
        final = s <= spc
        sol = minimise_iae(make(s), u, max_iter=max_iter)
        its += sol.iterations
        if final:
            return Solution(sol.u, sol.iae, its, sol.radius)
        u, s = np.repeat(sol.u, 2), s // 2


def _optimise_window(model: Model, amps: np.ndarray, args: dict, n_top: int, spc: int, levels: int,
                     t_open: float, starts: tuple, seed: int, max_iter: int) -> _Window:
    """Optimise a window of ``n_top`` intervals of the cascade's coarsest grid from every start down to intervals
    of ``spc`` steps (``levels`` grids), refine the best on a grid twice as fine, and evaluate it over the whole
    horizon (``amps`` long)."""
    top = spc * 2 ** (levels - 1)
    n_window = n_top * top
    n_opt = min(len(amps), n_window + int(round(HOLD / args["dt"])))

    def make(s: int, n: int = n_opt) -> Problem:
        return make_problem(model, spc=s, n_ctrl=n_window // s, n_steps=n, amps=amps[:n], **args)

    results = {}
    for name in starts:
        sol = cascade(make, start_profile(name, make(top), t_open, seed), top, spc, max_iter)
        results[name] = (sol, first_order_check(make(spc), sol.u, math.inf)[0])
    best = min((r[0] for r in results.values()), key=lambda s: s.iae)
    fine_problem = make(spc // 2)
    fine = minimise_iae(fine_problem, np.repeat(best.u, 2), max_iter=max_iter)
    full = make(spc // 2, len(amps))
    X = full.simulate(fine.u)
    werr = full.weights() * np.abs(X[:, model.out] - args["target"])
    total = float(werr.sum())
    return _Window(results, fine_problem, fine, X, full.idx, total, float(werr[n_window:].sum()) / total, n_window)


def _solve(task, amplitude, t_step, t_end, plant, limit, friction, grid, dt, window, starts, seed,
           max_iter) -> StepBound:
    """:func:`step_bound` on validated arguments."""
    clock = time.perf_counter()
    model = plant_model(task, plant)
    n_total = int(round((t_end - t_step) / dt))
    amps = _amplitudes(friction, t_step, dt, n_total)
    u_hold = hold_current(task, amplitude, model, limit, float(amps[-1]))
    args = {"target": amplitude, "limit": limit, "u_hold": u_hold, "dt": dt}
    spc = int(round(grid / dt))
    opened = make_problem(model, spc=n_total, n_ctrl=1, n_steps=n_total, amps=amps, **args)
    t_open = crossing_time(opened.simulate([math.copysign(limit, amplitude)])[:, model.out], amplitude, dt)
    if not math.isfinite(t_open):
        raise ValueError(f"amplitude {amplitude:g} {UNITS[task]} is not reached within t_end - t_step = "
                         f"{t_end - t_step:g} s even with the valve fully open: raise t_end or lower the step")
    top = grid * 2 ** (CASCADE[task] - 1)
    n_top = max(1, math.ceil((window if window is not None else WINDOW_FACTOR * t_open) / top - 1e-9))
    while True:
        if n_top * top > t_end - t_step + 1e-12:
            raise ValueError(f"t_end must leave room for the optimised window: t_end - t_step = {t_end - t_step:g} s "
                             f"is shorter than the {n_top * top:g} s this step needs")
        w = _optimise_window(model, amps, args, n_top, spc, CASCADE[task], t_open, starts, seed, max_iter)
        if w.tail_share <= TAIL_TOL or window is not None or 2 * n_top * top > t_end - t_step:
            break
        n_top *= 2
    bang = make_problem(model, spc=spc, n_ctrl=n_top * 2 ** (CASCADE[task] - 1), n_steps=n_total, amps=amps, **args)
    iae_bang = bang.iae(start_profile("bang-hold", bang, t_open, seed))
    y = w.X[:, model.out]
    t_reach = crossing_time(y, amplitude, dt)
    stat, saturated, switching = first_order_check(w.fine_problem, w.fine.u, t_reach)
    diag = _diagnostics(w, stat, saturated, switching, dt, time.perf_counter() - clock)
    u_steps = np.where(w.idx >= 0, w.fine.u[np.maximum(w.idx, 0)], u_hold)
    arrays = [t_step + np.arange(n_total + 1) * dt, y.copy(), np.append(u_steps, u_steps[-1]), w.X]
    for a in arrays:
        a.setflags(write=False)
    return StepBound(task, amplitude, t_step, t_end, limit, w.iae, *arrays, grid / 2, u_hold, t_reach, t_open,
                     iae_bang, diag)


def _diagnostics(w: _Window, stat: float, saturated: float, switching: float, dt: float,
                 wall: float) -> BoundDiagnostics:
    """The gap estimates of one optimised window."""
    by_start = tuple((name, sol.iae, st) for name, (sol, st) in w.starts.items())
    stationary = [iae for _, iae, st in by_start if st <= STATIONARY_TOL]
    lo = min(iae for _, iae, _ in by_start)
    spread = (max(stationary) - min(stationary)) / min(stationary) if stationary else math.nan
    return BoundDiagnostics(
        iae_by_start=by_start, start_spread=spread, n_stationary=len(stationary), iae_coarse=lo,
        iae_fine=w.fine.iae, refinement=(lo - w.fine.iae) / w.fine.iae,
        iterations=sum(sol.iterations for sol, _ in w.starts.values()) + w.fine.iterations, stationarity=stat,
        saturated_share=saturated, switching_share=switching, tail_share=w.tail_share, window=w.n_window * dt,
        wall_time=wall)


# --- The default law on the same step, the figure and the command ------------------------------------------------


def law_step(task: str, amplitude: float, *, t_step: float, t_end: float, friction: tuple = ()):
    """The env's default law (its settings, with a bumpless start) on the step from rest, logged every control
    period: a :class:`~ehss_gym.core.sim.Trajectory` whose ``y`` and ``r`` give its IAE (:func:`step_iae`)."""
    tpl = EnvConfig.from_kwargs({"task": task, "bumpless": True}).template()
    return simulate(tpl.replace(reference=step(amplitude, t_step), friction=friction, t_end=t_end,
                                log_interval=tpl.control_period))


def step_iae(t, y, amplitude: float, t_step: float) -> float:
    """IAE [output unit * s] of samples y(t) against r = A [t >= t_step]: the trapezoid rule before the step (r = 0)
    and from it (r = A), y interpolated at t_step so no interval straddles the jump."""
    t = np.asarray(t, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    ys = float(np.interp(t_step, t, y))
    pre, post = t < t_step, t > t_step
    tp, yp = np.append(t[pre], t_step), np.append(y[pre], ys)
    tq, yq = np.insert(t[post], 0, t_step), np.insert(y[post], 0, ys)
    return float(np.trapezoid(np.abs(yp), tp) + np.trapezoid(np.abs(yq - amplitude), tq))


def bound_figure(bounds, laws=None, path=None, *, made_by: str | None = None):
    """One column per bound: y(t) of the optimal profile (and of each run in ``laws``, Trajectories on the same
    steps) against the reference, and the currents [mA], over the time from the step [ms]. Saves to ``path``
    and returns it, or returns the figure if ``path`` is None."""
    fig = Figure(figsize=(3.2 * len(bounds) + 0.8, 5.2))  # no pyplot: no backend chosen, no global state
    axes = fig.subplots(2, len(bounds), sharex="col", squeeze=False)
    for k, b in enumerate(bounds):
        law = laws[k] if laws else None
        span = 3.0 * b.diagnostics.window
        if law is not None:
            span = max(span, 1.5 * crossing_time(law.y[law.t >= b.t_step], b.amplitude, law.scenario.control_period))
        span = min(span, b.t_end - b.t_step) if math.isfinite(span) else b.t_end - b.t_step
        ax_y, ax_u = axes[0, k], axes[1, k]
        sel = b.t <= b.t_step + span
        ax_y.plot(1e3 * (b.t[sel] - b.t_step), np.full(sel.sum(), b.amplitude), "k:", lw=0.8, label="r")
        ax_y.plot(1e3 * (b.t[sel] - b.t_step), b.y[sel], lw=1.2, label=f"bound, IAE {b.iae_bound:.3g}")
        ax_u.step(1e3 * (b.t[sel] - b.t_step), b.u[sel], where="post", lw=0.8, label="bound")
        if law is not None:
            ls = (law.t >= b.t_step) & (law.t <= b.t_step + span)
            iae = step_iae(law.t, law.y, b.amplitude, b.t_step)
            ax_y.plot(1e3 * (law.t[ls] - b.t_step), law.y[ls], lw=1.0, label=f"default law, IAE {iae:.3g}")
            ax_u.step(1e3 * (law.t[ls] - b.t_step), law.u_applied[ls], where="post", lw=0.8, label="default law")
        ax_y.set_title(f"{b.task} step {b.amplitude:g} {b.unit}", fontsize=9)
        ax_y.legend(fontsize=7, loc="lower right")
        ax_u.set_xlabel("time from the step [ms]")
        ax_u.legend(fontsize=7, loc="upper right")
    axes[0, 0].set_ylabel("y [output unit]")
    axes[1, 0].set_ylabel("current u [mA]")
    if made_by:
        fig.text(0.01, 0.005, f"made by: {made_by}", fontsize=7, color="gray")
    fig.tight_layout(rect=(0, 0.02, 1, 1))
    if path is None:
        return fig
    fig.savefig(path, dpi=120)
    return str(path)


TABLE_FIELDS = ("task", "amplitude", "unit", "iae_bound", "iae_law", "ratio", "t_reach_ms", "t_reach_open_ms",
                "t_reach_law_ms", "iae_bang_hold", "start_spread", "n_stationary", "refinement", "stationarity",
                "saturated_share", "switching_share", "tail_share", "window_s", "wall_s")


def bound_row(b: StepBound, law) -> dict:
    """One row of the bound table: the bound, the law's IAE and their ratio, the reach times and the gap."""
    d = b.diagnostics
    iae_law = step_iae(law.t, law.y, b.amplitude, b.t_step)
    t_law = crossing_time(law.y[law.t >= b.t_step], b.amplitude, law.scenario.control_period)
    return {"task": b.task, "amplitude": b.amplitude, "unit": b.unit, "iae_bound": b.iae_bound, "iae_law": iae_law,
            "ratio": b.ratio(iae_law), "t_reach_ms": 1e3 * b.t_reach, "t_reach_open_ms": 1e3 * b.t_reach_open,
            "t_reach_law_ms": 1e3 * t_law, "iae_bang_hold": b.iae_bang_hold, "start_spread": d.start_spread,
            "n_stationary": f"{d.n_stationary}/{len(d.iae_by_start)}", "refinement": d.refinement,
            "stationarity": d.stationarity, "saturated_share": d.saturated_share,
            "switching_share": d.switching_share, "tail_share": d.tail_share, "window_s": d.window,
            "wall_s": d.wall_time}


def main(argv=None) -> int:
    """``python -m ehss_gym.study.bound --out DIR``: the bound and the default law's IAE on steps from rest, both
    tasks; prints the table and writes ``bound.csv`` and ``bound_<task>.png`` into DIR."""
    ap = argparse.ArgumentParser(prog="python -m ehss_gym.study.bound", description=main.__doc__)
    ap.add_argument("--out", required=True, help="folder for bound.csv and the figures")
    ap.add_argument("--tasks", nargs="+", default=list(TASKS), choices=list(TASKS))
    ap.add_argument("--amplitudes", nargs="+", type=float, default=[0.2, 0.5, 1.0, 1.5],
                    help="step sizes [output unit: rad/s velocity, rad position]")
    ap.add_argument("--t-step", type=float, default=0.05, help="step time [s]")
    ap.add_argument("--t-end", type=float, default=1.0, help="end of the IAE window [s]")
    a = ap.parse_args(argv)
    out = pathlib.Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    made_by = "python -m ehss_gym.study.bound --out " + a.out
    rows = []
    for task in a.tasks:
        pairs = [(step_bound(task, amp, t_step=a.t_step, t_end=a.t_end),
                  law_step(task, amp, t_step=a.t_step, t_end=a.t_end)) for amp in a.amplitudes]
        rows += [bound_row(b, law) for b, law in pairs]
        bound_figure([b for b, _ in pairs], [law for _, law in pairs], out / f"bound_{task}.png", made_by=made_by)
    with open(out / "bound.csv", "w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=TABLE_FIELDS)
        w.writeheader()
        w.writerows(rows)
    print(md_table(TABLE_FIELDS, [[fmt_cell(r[k], 4) for k in TABLE_FIELDS] for r in rows]))
    print(f"\nwritten: {out / 'bound.csv'}, " + ", ".join(str(out / f"bound_{t}.png") for t in a.tasks))
    return 0


__all__ = ["step_bound", "bound_inputs", "StepBound", "BoundDiagnostics", "law_step", "step_iae", "bound_figure",
           "bound_row", "crossing_time", "hold_current", "Model", "Problem", "make_problem", "plant_model",
           "minimise_iae", "cascade", "first_order_check", "linear_step", "lag_model", "SIM_STEP", "START_NAMES"]


if __name__ == "__main__":
    raise SystemExit(main())
