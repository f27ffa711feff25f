"""Gymnasium environment ``EHSSTracking-v0``: the EHSS servo loop with a residual (or direct) RL action.

The env is a thin adapter over the compiled core (:func:`ehss_gym.core.sim.lanes_period`): it holds the
state and the RNG, and one compiled call (:func:`advance`) advances ``agent_period`` control periods for
B lanes. The single env uses B = 1, the vector env (:mod:`ehss_gym.envs.vector`) B = N, so both run the
same code and give identical results for the same seeds.

All defaults live in :data:`DEFAULTS` (one place, so they can be revisited); see :class:`EHSSTrackingEnv`
for the specification.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import gymnasium as gym
import numba as nb
import numpy as np
from gymnasium import spaces

from ehss_gym.core import layout as L
from ehss_gym.core.control import controller_update
from ehss_gym.core.metrics import summarize_acc
from ehss_gym.core.params import PlantParams, check_finite
from ehss_gym.core.physics import N_LANE_CONST, jit, jit_noalloc, lane_constants
from ehss_gym.core.scenarios import (
    DEFAULT_DISTRIBUTION,
    PHYSICAL_FIELDS,
    TRAIN_SEED_LIMIT,
    controller_mismatch,
    describe,
    paper_scenario,
    sample_scenario,
)
from ehss_gym.core.signals import reference_value
from ehss_gym.core.sim import TASKS, Scenario, check_n, ctrl_row, filter_block, init_filters, lanes_period

# ---------------------------------------------------------------------------------------------------
# Defaults: the reproduction study's recommendation (reports/paper/recommended_defaults.json) where it
# has one; evidence for every value in docs/ENV.md.


@dataclass(frozen=True)
class TaskDefaults:
    """Per-task defaults.

    Attributes:
        fr: combined-error cutoff f_r [Hz].
        sigma: CLF scale sigma [unit of s].
        smoothing: sign(s) smoothing width w [unit of s].
        estimator_hz: output-derivative estimator cutoff [Hz].
        error_scale: tracking-error scale of the reward and observation [output unit].
    """

    fr: float
    sigma: float
    smoothing: float
    estimator_hz: float
    error_scale: float


@dataclass(frozen=True)
class EnvDefaults:
    """Every default of the env in one place.

    Attributes:
        n: CLF power factor.
        mode: "residual" or "direct".
        current_limit: valve current limit [mA].
        control_period: controller sample time h [s].
        substeps: RK4 plant steps per control period.
        agent_period: control periods per agent step.
        residual_scale: current of a unit action [mA] when current_limit is None (else the current limit).
        estimator: filter scheme of the reference model and the derivative estimator ("foh", "zoh", "analog").
        scenario: "random" or "paper".
        reward_weights: track, effort, rate, tv, tv_u, divergence weights.
        velocity, position: per-task defaults.
    """

    n: int = 2
    mode: str = "residual"
    current_limit: float = 10.0
    control_period: float = 5e-5
    substeps: int = 1
    agent_period: int = 5
    residual_scale: float = 10.0
    estimator: str = "foh"
    scenario: str = "random"
    reward_weights: tuple = (("track", 1.0), ("effort", 0.05), ("rate", 0.05), ("tv", 0.0), ("tv_u", 0.0),
                             ("divergence", 10.0))
    velocity: TaskDefaults = field(default_factory=lambda: TaskDefaults(
        fr=60.0, sigma=1e5, smoothing=1e3, estimator_hz=1000.0, error_scale=1e-2))
    position: TaskDefaults = field(default_factory=lambda: TaskDefaults(
        fr=20.0, sigma=1e6, smoothing=100.0, estimator_hz=1000.0, error_scale=1e-2))


DEFAULTS = EnvDefaults()
MODES = ("residual", "direct")
SCENARIOS = ("random", "paper")
REWARD_KEYS = ("track", "effort", "rate", "tv", "tv_u", "divergence")
MAX_EVENTS = 4  # friction-event slots per lane (grown on demand)

# Observation normalisation (see the class docstring).
OBS_BOUND = 10.0  # observations are clipped to [-OBS_BOUND, OBS_BOUND] after the symlog squash
U_SCALE = 0.1  # [mA], order of the nominal tracking current
Y_SCALE = 1.0  # [output unit]
W_Y = 10.0  # [rad/s], time scale of the reference derivatives

# Per-agent-step statistics and reward-weight slots of the kernel.
S_SUM_E2, S_N, S_SAT, S_TV0 = 0, 1, 2, 3  # S_TV0: the lane's accumulated control TV when the step began
N_STATS = 4
W_TRACK, W_EFFORT, W_RATE, W_TV, W_TVU, W_DIV, W_INV_E2, W_INV_SCALE = range(8)
N_WEIGHTS = 8

# Per-lane float64 buffer F (B, N_F): column blocks, so one kernel argument carries them all (numba's
# dispatch costs ~0.1 us per array argument, a large share of a 15 us step).
N_PARAM = len(PlantParams._fields)
F_Z = 0  # loop state (N_LOOP)
F_PLANT = F_Z + L.N_LOOP  # true plant parameters
F_MODEL = F_PLANT + N_PARAM  # controller's model parameters
F_CTRL = F_MODEL + N_PARAM  # controller row (N_CTRL)
F_REF = F_CTRL + L.N_CTRL  # reference spec (N_REF)
F_INFO = F_REF + L.N_REF  # control-step info (N_INFO), scratch alternating with F_INFO_OK
F_INFO_OK = F_INFO + L.N_INFO  # last finite control-step info
F_PEEK = F_INFO_OK + L.N_INFO  # the controller's view at the next sample
F_PEEKZ = F_PEEK + L.N_INFO  # loop state after that sample's filter advance (N_LOOP; must follow F_PEEK)
F_ACC = F_PEEKZ + L.N_LOOP  # metrics accumulator (N_METRICS)
F_ZPREV = F_ACC + L.N_METRICS  # loop state at the last sample (scratch of lanes_period)
F_STATS = F_ZPREV + L.N_LOOP  # per-agent-step statistics (N_STATS)
F_URES = F_STATS + N_STATS  # residual current [mA]
F_REW = F_URES + 1  # reward of the last step
F_APREV = F_REW + 1  # previous normalised action
N_F = F_APREV + 1
# Per-lane int64 buffer: step index k, agent steps taken, group id (scratch).
IB_K, IB_NSTEP, IB_GID = 0, 1, 2
N_IB = 3
# Per-lane bool buffer: running (not diverged, not held), group member (scratch), F_PEEK/F_PEEKZ hold
# the controller's view at the lane's next period (set by the look-ahead, cleared when used or reloaded).
BB_RUN, BB_ACT, BB_PRE = 0, 1, 2
N_BB = 3
# Observation layout rows (3, D): info index, scale, flags (1 = symlog squash, 2 = from the last period).
LAY_SRC, LAY_SCALE, LAY_FLAGS = 0, 1, 2
FLAG_SQUASH, FLAG_LAST = 1, 2


# ---------------------------------------------------------------------------------------------------
# Compiled kernels


@jit
def _write_obs(obs_row, peek_row, last_row, lay):
    """Observation of one lane: symlog(x / scale), clipped, finite.

    x is read from ``peek_row`` (what the controller sees at the next sample) or, for entries flagged
    FLAG_LAST, from ``last_row`` (the last control period actually run: applied current, residual).
    """
    for i in range(lay.shape[1]):
        j = int(lay[LAY_SRC, i])
        fl = int(lay[LAY_FLAGS, i])
        v = (last_row[j] if fl & FLAG_LAST else peek_row[j]) / lay[LAY_SCALE, i]
        if not math.isfinite(v):
            v = OBS_BOUND if v > 0.0 else (-OBS_BOUND if v < 0.0 else 0.0)
        if fl & FLAG_SQUASH:
            v = math.copysign(math.log1p(abs(v)), v)
        if v > OBS_BOUND:
            v = OBS_BOUND
        elif v < -OBS_BOUND:
            v = -OBS_BOUND
        obs_row[i] = v


@jit_noalloc
def _peek(F, BB, b, k, h, events, filt, work):
    """Fill lane b's F_PEEK block with what its controller sees at sample k, without advancing it.

    The filters are advanced on a copy of the loop state, kept in F_PEEKZ, and BB_PRE is set: the lane's
    next control period (at this k, from this state) reuses all of it and only applies its residual
    (see :func:`ehss_gym.core.sim.lanes_period`), so look-ahead and step share one controller evaluation.
    """
    zt = F[b, F_PEEKZ:F_PEEKZ + L.N_LOOP]
    for i in range(L.N_LOOP):
        zt[i] = F[b, F_Z + i]
    controller_update(zt, k, h, F[b, F_PLANT:F_PLANT + N_PARAM], F[b, F_MODEL:F_MODEL + N_PARAM],
                      F[b, F_CTRL:F_CTRL + L.N_CTRL], F[b, F_REF:F_REF + L.N_REF], events[b], filt[b], F[b, F_URES],
                      F[b, F_PEEK:F_PEEK + L.N_INFO], work)
    BB[b, BB_PRE] = True


@jit
def observe(h, F, IB, BB, events, filt, work, obs, lay):
    """Observations of the lanes flagged in BB[:, BB_ACT] at their current step, without advancing them.

    Used at reset: the last-period block (applied current, residual) is zeroed, nothing was applied yet.
    """
    for b in range(F.shape[0]):
        if not BB[b, BB_ACT]:
            continue
        F[b, F_INFO_OK:F_INFO_OK + L.N_INFO] = 0.0
        _peek(F, BB, b, IB[b, IB_K], h, events, filt, work)
        _write_obs(obs[b], F[b, F_PEEK:F_PEEK + L.N_INFO], F[b, F_INFO_OK:F_INFO_OK + L.N_INFO], lay)


@jit_noalloc
def advance(n_per, h, substeps, F, IB, BB, events, filt, c, X, U, work, lwork, obs, elog, lay, wts):
    """Advance ``n_per`` control periods for every running lane; the env's one compiled step.

    Lanes are grouped by their step index k (lanes reset at different times are out of phase) and each
    group is stepped by :func:`ehss_gym.core.sim.lanes_period`, so a lane's arithmetic does not depend on
    the others. Per lane this then writes the observation (from the controller's view at the next
    sample, so the agent acts on the freshest measurement), the reward, the agent-rate error log, and
    clears the run flag if the lane diverged (the F_INFO_OK block keeps the last finite sample).

    Args:
        n_per: control periods per agent step.
        h, substeps: control period [s] and RK4 substeps.
        F: per-lane float64 buffer (B, N_F), blocks F_* (state, rows, info, metrics, residual [mA], ...).
        IB: per-lane int64 buffer (B, N_IB): step index, agent steps taken, scratch.
        BB: per-lane bool buffer (B, N_BB): run flag (cleared on divergence), scratch.
        events: friction events (B, E, 3); filt: filter blocks (B, 3, 4, 4).
        c, X, U, work, lwork: lane scratch (see :class:`ehss_gym.core.sim.LaneScratch`).
        obs: (B, D) float32 observations (output); lay: observation layout (3, D).
        elog: (B, T) float32 error at the last sample of each agent step.
        wts: reward weights (N_WEIGHTS,).
    """
    B = F.shape[0]
    z = F[:, F_Z:F_Z + L.N_LOOP]
    plant = F[:, F_PLANT:F_PLANT + N_PARAM]
    model = F[:, F_MODEL:F_MODEL + N_PARAM]
    ctrl = F[:, F_CTRL:F_CTRL + L.N_CTRL]
    ref = F[:, F_REF:F_REF + L.N_REF]
    info = F[:, F_INFO:F_INFO + L.N_INFO]
    info_ok = F[:, F_INFO_OK:F_INFO_OK + L.N_INFO]
    acc = F[:, F_ACC:F_ACC + L.N_METRICS]
    zprev = F[:, F_ZPREV:F_ZPREV + L.N_LOOP]
    u_res = F[:, F_URES]
    run = BB[:, BB_RUN]
    act = BB[:, BB_ACT]
    pre = BB[:, BB_PRE]
    peek = F[:, F_PEEK:F_PEEK + L.N_INFO + L.N_LOOP]
    for b in range(B):
        IB[b, IB_GID] = -1
        for j in range(N_STATS):
            F[b, F_STATS + j] = 0.0
    g = 0
    for b0 in range(B):
        if not run[b0] or IB[b0, IB_GID] >= 0:
            continue
        kk = IB[b0, IB_K]
        for b in range(B):
            member = run[b] and IB[b, IB_GID] < 0 and IB[b, IB_K] == kk
            act[b] = member
            if member:
                IB[b, IB_GID] = g
                F[b, F_STATS + S_TV0] = acc[b, L.M_TV_U]
        for j in range(n_per):
            # Periods alternate between the F_INFO and F_INFO_OK blocks, so the last finite period's info
            # survives a divergence in the next one without a per-period copy (lanes only ever stop).
            inf = info if j % 2 == 0 else info_ok
            n_act = lanes_period(z, kk + j, h, substeps, plant, model, ctrl, ref, events, filt, u_res, act, inf, acc,
                                 c, X, U, zprev, work, lwork, pre, peek)
            for b in range(B):
                if act[b]:
                    e = inf[b, L.I_E]
                    F[b, F_STATS + S_SUM_E2] += e * e
                    F[b, F_STATS + S_N] += 1.0
                    F[b, F_STATS + S_SAT] += inf[b, L.I_SAT]
            if n_act == 0:
                break
        for b in range(B):
            if IB[b, IB_GID] != g:
                continue
            # S_N finite periods ran: the last one (index S_N - 1) wrote F_INFO if its index is even
            n_ok = int(F[b, F_STATS + S_N])
            if n_ok > 0 and (n_ok - 1) % 2 == 0:
                for i in range(L.N_INFO):
                    info_ok[b, i] = info[b, i]
            diverged = not act[b]
            run[b] = act[b]
            IB[b, IB_K] = kk + n_per
            a = u_res[b] * wts[W_INV_SCALE]
            da = 0.5 * (a - F[b, F_APREV])
            r = -wts[W_EFFORT] * a * a - wts[W_RATE] * da * da - wts[W_TV] * abs(da)
            n = F[b, F_STATS + S_N]
            if n > 0.0:
                r -= wts[W_TVU] * (acc[b, L.M_TV_U] - F[b, F_STATS + S_TV0]) / n * wts[W_INV_SCALE]
            if diverged:
                r -= wts[W_DIV]
            elif n > 0.0:
                r += wts[W_TRACK] / (1.0 + F[b, F_STATS + S_SUM_E2] / n * wts[W_INV_E2])
            F[b, F_REW] = r
            F[b, F_APREV] = a
            j = IB[b, IB_NSTEP]
            if j < elog.shape[1]:
                elog[b, j] = info_ok[b, L.I_E]
            IB[b, IB_NSTEP] = j + 1
            _peek(F, BB, b, kk + n_per, h, events, filt, work)
            _write_obs(obs[b], F[b, F_PEEK:F_PEEK + L.N_INFO], info_ok[b], lay)
        g += 1


@nb.njit(parallel=True, cache=True, error_model="numpy")
def advance_chunks(chunk, n_per, h, substeps, F, IB, BB, events, filt, c, X, U, work, lwork, obs, elog, lay, wts):
    """:func:`advance` on chunks of ``chunk`` lanes in parallel; per-chunk scratch c, X, U, work, lwork."""
    n_chunks = c.shape[0]
    for i in nb.prange(n_chunks):
        s = i * chunk
        e = s + chunk
        advance(n_per, h, substeps, F[s:e], IB[s:e], BB[s:e], events[s:e], filt[s:e], c[i], X[i], U[i], work[i],
                lwork[i], obs[s:e], elog[s:e], lay, wts)


# ---------------------------------------------------------------------------------------------------
# Settings


def _choice(name, value, valid):
    if value not in valid:
        raise ValueError(f"{name} must be one of {list(valid)}, got {value!r}")
    return value


def _int_at_least(name, value, low):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer, float)) or not float(value).is_integer() \
            or value < low:
        raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
    return int(value)


def _positive(name, value):
    return check_finite(name, value, low=0.0, low_open=True)


@dataclass(frozen=True)
class EnvConfig:
    """Validated settings of an :class:`EHSSTrackingEnv` (see its docstring for each field)."""

    task: str
    n: int
    fr: float
    sigma: float
    smoothing: float
    mode: str
    residual_scale: float
    agent_period: int
    control_period: float
    substeps: int
    current_limit: float | None
    estimator_hz: float
    estimator: str
    scenario: object
    reward_weights: dict
    error_scale: float
    episode_seconds: float | None

    KEYS = ("task", "n", "fr", "sigma", "smoothing", "mode", "residual_scale", "agent_period", "control_period",
            "substeps", "current_limit", "estimator_hz", "estimator", "scenario", "reward_weights", "error_scale",
            "episode_seconds")

    @classmethod
    def from_kwargs(cls, kwargs: dict) -> EnvConfig:
        """Validate keyword arguments; unknown names or bad values raise ValueError listing what is valid."""
        unknown = sorted(set(kwargs) - set(cls.KEYS))
        if unknown:
            raise ValueError(f"unknown keyword argument(s) {unknown}; valid: {list(cls.KEYS) + ['render_mode']}")
        d = DEFAULTS
        task = _choice("task", kwargs.get("task", "velocity"), tuple(TASKS))
        td: TaskDefaults = getattr(d, task)
        mode = _choice("mode", kwargs.get("mode", d.mode), MODES)
        n = kwargs.get("n", d.n)
        check_n(n)
        fr = _positive("fr", kwargs.get("fr", td.fr))
        sigma = _positive("sigma", kwargs.get("sigma", td.sigma))
        smoothing = check_finite("smoothing", kwargs.get("smoothing", td.smoothing), low=0.0)
        limit = kwargs.get("current_limit", d.current_limit)
        if limit is not None:
            limit = _positive("current_limit", limit)
        scale = kwargs.get("residual_scale")
        if scale is None:
            scale = d.residual_scale if limit is None else limit
        scale = _positive("residual_scale", scale)
        agent_period = _int_at_least("agent_period", kwargs.get("agent_period", d.agent_period), 1)
        h = check_finite("control_period", kwargs.get("control_period", d.control_period), low=1e-7, high=1e-2)
        substeps = _int_at_least("substeps", kwargs.get("substeps", d.substeps), 1)
        est = _positive("estimator_hz", kwargs.get("estimator_hz", td.estimator_hz))
        scheme = _choice("estimator", kwargs.get("estimator", d.estimator), L.ESTIMATORS)
        scenario = kwargs.get("scenario", d.scenario)
        if not (isinstance(scenario, Scenario) or scenario in SCENARIOS):
            raise ValueError(f"scenario must be one of {list(SCENARIOS)} or an ehss_gym.Scenario, got {scenario!r}")
        rw = dict(d.reward_weights)
        given = kwargs.get("reward_weights") or {}
        if not isinstance(given, dict):
            raise ValueError(f"reward_weights must be a dict with keys from {list(REWARD_KEYS)}, got {given!r}")
        bad = sorted(set(given) - set(REWARD_KEYS))
        if bad:
            raise ValueError(f"unknown reward_weights key(s) {bad}; valid: {list(REWARD_KEYS)}")
        for key, v in given.items():
            rw[key] = check_finite(f"reward_weights[{key!r}]", v, low=0.0)
        err = _positive("error_scale", kwargs.get("error_scale", td.error_scale))
        eps = kwargs.get("episode_seconds")
        if eps is not None:
            eps = check_finite("episode_seconds", eps, low=h * agent_period)
        cfg = cls(task=task, n=int(n), fr=fr, sigma=sigma, smoothing=smoothing, mode=mode, residual_scale=scale,
                  agent_period=agent_period, control_period=h, substeps=substeps, current_limit=limit,
                  estimator_hz=est, estimator=scheme, scenario=scenario, reward_weights=rw, error_scale=err,
                  episode_seconds=eps)
        if isinstance(scenario, Scenario):
            cfg.check_pinned(scenario)
        return cfg

    @property
    def order(self) -> int:
        return TASKS[self.task]

    @property
    def agent_dt(self) -> float:
        """Duration of one agent step [s]."""
        return self.agent_period * self.control_period

    def template(self) -> Scenario:
        """A Scenario with these controller settings (its physical fields are the paper's)."""
        return paper_scenario(Scenario(task=self.task, n=self.n, fr=self.fr, sigma=self.sigma,
                                       smoothing=self.smoothing, current_limit=self.current_limit,
                                       control_period=self.control_period, substeps=self.substeps,
                                       estimator_hz=self.estimator_hz, estimator=self.estimator))

    def check_pinned(self, sc: Scenario) -> None:
        """A pinned Scenario must carry exactly these controller settings."""
        if not isinstance(sc, Scenario):
            raise ValueError(f"scenario must be 'random', 'paper', a dict of {list(PHYSICAL_FIELDS)} or a "
                             f"Scenario, got {sc!r}")
        diff = controller_mismatch(sc, self.template())
        if diff:
            raise ValueError(f"pinned Scenario differs from the env's controller settings in {diff}; build it from "
                             "env.unwrapped.scenario_template.replace(...) (only "
                             f"{list(PHYSICAL_FIELDS)} may differ)")
        if sc.n_steps < self.agent_period:
            raise ValueError(f"scenario t_end ({sc.t_end:g} s) is shorter than one agent step ({self.agent_dt:g} s)")


# ---------------------------------------------------------------------------------------------------
# Observation layout


def observation_layout(cfg: EnvConfig) -> list[tuple[str, int, float, bool, str]]:
    """(name, info index, scale, squashed, unit) of each observation entry; see the class docstring."""
    m = cfg.order
    unit = "rad/s" if cfg.task == "velocity" else "rad"
    wr = 2.0 * math.pi * cfg.fr
    p = PlantParams()
    out = []
    for i in range(m):
        out.append((f"e_d{i}" if i else "e", L.I_E + i, cfg.error_scale * wr**i, True, f"{unit}/s^{i}"))
    out.append(("s", L.I_S, cfg.error_scale * wr ** (m - 1), True, f"{unit}/s^{m - 1}"))
    for i in range(m + 1):
        out.append((f"y_ref_d{i}" if i else "y_ref", L.I_YD + i, Y_SCALE * W_Y**i, True, f"{unit}/s^{i}"))
    out.append(("x1", L.I_XM + 0, 1.0, True, "rad"))
    out.append(("x2", L.I_XM + 1, 1.0, True, "rad/s"))
    out.append(("x3", L.I_XM + 2, p.P_s, True, "Pa"))
    out.append(("x4", L.I_XM + 3, p.K * U_SCALE, True, "m^2"))
    out.append(("u_applied", L.I_UAPP, U_SCALE, True, "mA"))
    out.append(("u_base", L.I_UBASE, U_SCALE, True, "mA"))
    out.append(("last_action", L.I_URES, cfg.residual_scale, False, "-"))
    return out


def symlog_inverse(v):
    """Inverse of the observation squash sign(x) log(1 + |x|)."""
    v = np.asarray(v, dtype=np.float64)
    return np.sign(v) * np.expm1(np.abs(v))


def decode_observation(obs, layout) -> dict[str, np.ndarray]:
    """Physical values (in the units of :func:`observation_layout`) from observations (..., D)."""
    obs = np.asarray(obs, dtype=np.float64)
    out = {}
    for i, (name, _, scale, squash, _) in enumerate(layout):
        v = obs[..., i]
        out[name] = (symlog_inverse(v) if squash else v) * scale
    return out


# ---------------------------------------------------------------------------------------------------
# Lanes: the arrays of B loops, shared by the single and the vector env


class Lanes:
    """State and scratch arrays of B closed loops (padded to whole chunks) and the calls into the kernels."""

    def __init__(self, cfg: EnvConfig, n_lanes: int, chunk: int | None = None):
        self.cfg = cfg
        self.chunk = n_lanes if chunk is None else chunk
        self.n_chunks = -(-n_lanes // self.chunk)
        B = self.B = self.n_chunks * self.chunk
        self.n_lanes = n_lanes
        tmpl = cfg.template()
        base = ctrl_row(tmpl)
        base[L.C_BASE] = 1.0 if cfg.mode == "residual" else 0.0
        self.ctrl_base = base
        nominal = PlantParams().as_array()
        self.F = np.zeros((B, N_F))
        self.IB = np.zeros((B, N_IB), dtype=np.int64)
        self.BB = np.zeros((B, N_BB), dtype=np.bool_)
        # named views into the buffers (writes go to F, IB, BB)
        self.z = self.F[:, F_Z:F_Z + L.N_LOOP]
        self.plant = self.F[:, F_PLANT:F_PLANT + N_PARAM]
        self.model = self.F[:, F_MODEL:F_MODEL + N_PARAM]
        self.ctrl = self.F[:, F_CTRL:F_CTRL + L.N_CTRL]
        self.ref = self.F[:, F_REF:F_REF + L.N_REF]
        self.info_ok = self.F[:, F_INFO_OK:F_INFO_OK + L.N_INFO]
        self.acc = self.F[:, F_ACC:F_ACC + L.N_METRICS]
        self.stats = self.F[:, F_STATS:F_STATS + N_STATS]
        self.u_res = self.F[:, F_URES]
        self.rew = self.F[:, F_REW]
        # lane 0's rows, pre-made for the single env's step: stats (N_STATS), residual and reward in one view
        self.info_ok0 = self.info_ok[0]
        self.tail0 = self.F[0, F_STATS:F_REW + 1]
        self.k = self.IB[:, IB_K]
        self.nstep = self.IB[:, IB_NSTEP]
        self.run = self.BB[:, BB_RUN]
        self.plant[:] = nominal
        self.model[:] = nominal
        self.ctrl[:] = base
        self.events = self._empty_events(B, MAX_EVENTS)
        self.filt = np.tile(filter_block(cfg.order, tmpl.ref_model_hz, cfg.estimator_hz, cfg.control_period,
                                         cfg.estimator), (B, 1, 1, 1))
        self.c = np.zeros((self.n_chunks, N_LANE_CONST, self.chunk))
        for i in range(self.n_chunks):
            lane_constants(np.ascontiguousarray(self.plant[i * self.chunk:(i + 1) * self.chunk]), self.c[i])
        self.X = np.zeros((self.n_chunks, L.N_LOOP, self.chunk))
        self.U = np.zeros((self.n_chunks, self.chunk))
        self.work = np.zeros((self.n_chunks, 8, 4))
        self.lwork = np.zeros((self.n_chunks, 6, L.N_LOOP, self.chunk))
        self.layout = observation_layout(cfg)
        self.lay = np.zeros((3, len(self.layout)))
        for i, (_, src, scale, squash, _) in enumerate(self.layout):
            self.lay[LAY_SRC, i] = src
            self.lay[LAY_SCALE, i] = scale
            self.lay[LAY_FLAGS, i] = (FLAG_SQUASH if squash else 0) + (FLAG_LAST if src in (L.I_UAPP, L.I_URES) else 0)
        self.obs = np.zeros((B, len(self.layout)), dtype=np.float32)
        self.obs0 = self.obs[0]
        rw = cfg.reward_weights
        self.wts = np.zeros(N_WEIGHTS)
        self.wts[W_TRACK] = rw["track"]
        self.wts[W_EFFORT] = rw["effort"]
        self.wts[W_RATE] = rw["rate"]
        self.wts[W_TV] = rw["tv"]
        self.wts[W_TVU] = rw["tv_u"]
        self.wts[W_DIV] = rw["divergence"]
        self.wts[W_INV_E2] = 1.0 / cfg.error_scale**2
        self.wts[W_INV_SCALE] = 1.0 / cfg.residual_scale
        self.elog = np.zeros((B, 1), dtype=np.float32)
        self.T = np.zeros(B, dtype=np.int64)  # agent steps in each lane's episode
        self.scenarios: list[Scenario | None] = [None] * B
        self.tmp_c = np.zeros((N_LANE_CONST, 1))
        self._bind()

    @staticmethod
    def _empty_events(B: int, E: int) -> np.ndarray:
        ev = np.zeros((B, E, 3))
        ev[:, :, L.F_START] = ev[:, :, L.F_END] = math.inf  # padding never fires
        return ev

    def load(self, b: int, sc: Scenario) -> None:
        """Put lane b at the start of scenario ``sc`` (rows as :meth:`ehss_gym.core.sim.LoopArrays.build` makes them)."""
        cfg = self.cfg
        if len(sc.friction) > self.events.shape[1]:
            ev = self._empty_events(self.B, len(sc.friction))
            ev[:, :self.events.shape[1]] = self.events
            self.events = ev
            self._bind()
        self.F[b] = 0.0
        self.plant[b] = sc.plant.as_array()
        self.model[b] = (sc.model or sc.plant).as_array()
        row = self.ctrl[b]
        row[:] = self.ctrl_base
        row[L.C_SEED] = sc.seed
        row[L.C_NOISE_THETA:L.C_NOISE_THETA + 4] = sc.noise_std
        row[L.C_OMEGA_MAX] = sc.omega_max
        row[L.C_P_BOUND] = sc.pressure_bound
        self.ref[b] = sc.reference.spec
        self.events[b, :, :] = 0.0
        self.events[b, :, L.F_START] = self.events[b, :, L.F_END] = math.inf
        if sc.friction:
            self.events[b, :len(sc.friction)] = sc.friction
        init_filters(self.z[b], self.filt[b], reference_value(0.0, self.ref[b]))
        lane_constants(self.plant[b:b + 1].copy(), self.tmp_c)
        self.c[b // self.chunk][:, b % self.chunk] = self.tmp_c[:, 0]
        self.acc[b, L.M_T_DIVERGED] = -1.0
        self.IB[b] = 0
        self.BB[b, BB_PRE] = False  # the look-ahead of the previous episode is stale
        self.run[b] = True
        T = sc.n_steps // cfg.agent_period
        self.T[b] = T
        if T > self.elog.shape[1]:
            el = np.zeros((self.B, T), dtype=np.float32)
            el[:, :self.elog.shape[1]] = self.elog
            self.elog = el
            self._bind()
        self.scenarios[b] = sc

    def observe(self, lanes) -> None:
        """Fill the observations of the given lanes from their current state (no time passes)."""
        self.BB[:, BB_ACT] = False
        self.BB[lanes, BB_ACT] = True
        observe(self.cfg.control_period, self.F, self.IB, self.BB, self.events, self.filt, self.work[0], self.obs,
                self.lay)

    def _bind(self) -> None:
        # Pre-bound kernel arguments: a step then costs one call, not a dozen attribute look-ups.
        cfg = self.cfg
        self._args = (cfg.agent_period, cfg.control_period, cfg.substeps, self.F, self.IB, self.BB, self.events,
                      self.filt, self.c[0], self.X[0], self.U[0], self.work[0], self.lwork[0], self.obs, self.elog,
                      self.lay, self.wts)
        self._pargs = (self.chunk, cfg.agent_period, cfg.control_period, cfg.substeps, self.F, self.IB, self.BB,
                       self.events, self.filt, self.c, self.X, self.U, self.work, self.lwork, self.obs, self.elog,
                       self.lay, self.wts)

    def advance_single(self) -> None:
        """One agent step of all lanes in one sequential call (needs a single chunk)."""
        advance(*self._args)

    def advance_parallel(self) -> None:
        """One agent step of all lanes, chunks in parallel threads."""
        advance_chunks(*self._pargs)

    def metrics(self, b: int) -> dict:
        """The core metrics summary of lane b's episode so far (with recovery times from the agent-rate log)."""
        sc = self.scenarios[b]
        n = int(min(self.IB[b, IB_NSTEP], self.elog.shape[1]))
        per = self.cfg.agent_period
        t = ((np.arange(n) + 1) * per - 1) * self.cfg.control_period
        return summarize_acc(self.acc[b], sc, t, self.elog[b, :n].astype(np.float64))

    def draw(self, b: int, cfg: EnvConfig, rng: np.random.Generator, options) -> tuple[Scenario, dict]:
        """Choose lane b's next scenario from the env setting and reset options; returns it and its info."""
        choice = cfg.scenario
        if options:
            bad = sorted(set(options) - {"scenario"})
            if bad:
                raise ValueError(f"unknown reset option(s) {bad}; valid: ['scenario']")
            choice = options.get("scenario", choice)
        tmpl = self.template
        info: dict = {}
        if isinstance(choice, Scenario):
            cfg.check_pinned(choice)
            sc = choice
            info["scenario_name"] = "pinned"
        elif isinstance(choice, dict):
            bad = sorted(set(choice) - set(PHYSICAL_FIELDS))
            if bad:
                raise ValueError(f"scenario dict has unknown field(s) {bad}; valid: {list(PHYSICAL_FIELDS)}")
            sc = paper_scenario(tmpl, cfg.episode_seconds).replace(**choice)
            info["scenario_name"] = "custom"
        elif choice == "paper":
            sc = paper_scenario(tmpl, cfg.episode_seconds)
            info["scenario_name"] = "paper"
        elif choice == "random":
            seed = int(rng.integers(0, TRAIN_SEED_LIMIT))
            sc = sample_scenario(seed, tmpl, cfg.episode_seconds, DEFAULT_DISTRIBUTION)
            info["scenario_name"] = "random"
            info["scenario_seed"] = seed
        else:
            raise ValueError(f"options['scenario'] must be one of {list(SCENARIOS)}, a dict of "
                             f"{list(PHYSICAL_FIELDS)} or a Scenario, got {choice!r}")
        if sc.n_steps < cfg.agent_period:
            raise ValueError(f"scenario t_end ({sc.t_end:g} s) is shorter than one agent step ({cfg.agent_dt:g} s)")
        info["scenario"] = describe(sc)
        return sc, info

    @property
    def template(self) -> Scenario:
        t = getattr(self, "_template", None)
        if t is None:
            t = self._template = self.cfg.template()
        return t


def parse_action_scalar(action) -> float:
    """A single action value from an array-like of one element; NaN raises ValueError."""
    if type(action) is np.ndarray and action.shape == (1,):
        v = float(action[0])
    else:
        a = np.asarray(action, dtype=np.float64)
        if a.size != 1:
            raise ValueError(f"action must have shape (1,), got shape {a.shape}")
        v = float(a.reshape(-1)[0])
    if v != v:
        raise ValueError("action is NaN; actions must be numbers in [-1, 1] (out-of-range values are clipped)")
    return v


# ---------------------------------------------------------------------------------------------------
# The env


class EHSSTrackingEnv(gym.Env):
    r"""EHSS servo tracking with a Sontag/CLF base law and a residual (or direct) RL action.

    **Plant and loop** (Mintsa et al., Eq. 1; see :mod:`ehss_gym.core.physics`)::

        x1' = x2                                    angular position [rad]
        x2' = (d_m x3 - B x2 - T_f) / J             angular velocity [rad/s]
        x3' = (4 beta / V_m)(Q(x3, x4) - d_m x2 - c_sm x3)   load pressure [Pa]
        x4' = (K u - x4) / tau                      valve opening area [m^2]

    with Coulomb friction events T_f (never observed). The output y is x2 (task "velocity", relative
    degree m = 3) or x1 ("position", m = 4). Every control period h (``control_period``) the digital
    controller samples (with sensor noise), forms the tracking errors e = y - y_d and their estimates
    from the state-variable filter, the combined error s = e^(m-1) + lambda_{m-2} e^(m-2) + ... and
    the Sontag current on V = (s/sigma)^n / n (:mod:`ehss_gym.core.control`)::

        u_base = -psi/G - sgn_w(s) sign(G) hypot(psi/G, |s/sigma|^(n-1) |G| / sigma)

    and applies, held over the period (ZOH, ``substeps`` RK4 steps)::

        residual mode:  u = clip(u_base + residual_scale * a, -current_limit, current_limit)
        direct mode:    u = clip(residual_scale * a, -current_limit, current_limit)

    The agent acts every ``agent_period`` control periods; its action a is held in between.

    **Action** ``Box(-1, 1, (1,), float32)``: a = the residual current over ``residual_scale`` [mA]
    (direct mode: the whole current; ``residual_scale`` defaults to ``current_limit``). Out-of-range
    values are clipped to [-1, 1] and counted (``info["clipped"]`` this step, ``info["n_clipped"]`` in
    the episode). A NaN action raises ValueError.

    **Observation** ``Box(-10, 10, (D,), float32)``, D = 15 (velocity) or 17 (position). Each entry
    is ``clip(sign(v) log(1 + |v|), -10, 10)`` with ``v = x / scale`` (only ``last_action`` is linear):
    about unit size in normal tracking, compressed in transients, never NaN. Values are what the
    controller sees at its next sample, at the end of the step (t = info["t"] + control_period, with
    that sample's sensor noise), so the agent acts on the freshest measurement; ``u_applied`` and
    ``last_action`` are those of the last period run (0 after reset). e^(i) are the estimator's
    values. Decode with :func:`decode_observation`. Output unit U = rad/s (velocity) or rad
    (position); w_r = 2 pi f_r.

    =============================  ============================  ===============================
    entries                        quantity                      scale
    =============================  ============================  ===============================
    e, e_d1, .., e_d(m-1)          e^(i) [U/s^i]                 error_scale * w_r^i
    s                              combined error [U/s^(m-1)]    error_scale * w_r^(m-1)
    y_ref, y_ref_d1, .., y_ref_dm  y_d^(i) [U/s^i]               1 * (10 rad/s)^i
    x1, x2                         measured x1 [rad], x2 [rad/s] 1
    x3                             measured x3 [Pa]              P_s = 9e6 Pa
    x4                             measured x4 [m^2]             K * 0.1 mA = 8e-8 m^2
    u_applied                      applied current [mA]          0.1 mA
    u_base                         Sontag current [mA] (also     0.1 mA
                                   computed, not applied, in
                                   direct mode)
    last_action                    previous a [-] (linear)       1
    =============================  ============================  ===============================

    **Reward**, per agent step over its control periods k (e_k the sampled error)::

        r = w_track / (1 + mean_k(e_k^2) / error_scale^2) - w_effort a^2 - w_rate ((a - a_prev)/2)^2
            - w_tv |a - a_prev|/2 - w_tv_u mean_k(|u_k - u_(k-1)|) / residual_scale
            - w_divergence [diverged this step]   (the tracking term is dropped on divergence)

    with a the clipped action and u_k the applied current [mA]. w_tv is an L1 rate penalty on the
    residual's own steps (the quadratic rate term hardly sees small jitter); w_tv_u charges the whole
    control total variation (the evaluation's TV, base-law switching included: a residual that tracks
    more tightly can make the base law switch more often without any step of its own). Range:
    [-(w_effort + w_rate + w_tv + 2 w_tv_u current_limit/residual_scale + w_divergence), w_track]; with
    the default weights (1, 0.05, 0.05, 0, 0, 10): [-10.1, 1].

    **Termination and truncation.** Divergence (non-finite value, |x2| > omega_max, |x3| > 1.5 P_s;
    see :mod:`ehss_gym.core.sim`) ends the episode with ``terminated=True``, ``info["diverged"]=True`` and
    ``info["divergence_reason"]``; the observation and info show the last finite state. The episode
    ends after floor(t_end / (agent_period h)) agent steps with ``truncated=True``. At either end,
    ``info["metrics"]`` holds the core metrics summary (:func:`ehss_gym.core.metrics.summarize_acc`, at the
    full control rate; recovery times from the agent-rate error log).

    **info** each step (values at the last control sample of the step): t [s], e, s, V, u_base,
    u_residual, u_applied [mA], saturated (limit active at that sample), sat_fraction (share of this
    step's control periods at the limit), friction_torque [N*m], clipped, n_clipped, diverged.
    ``reset`` returns the drawn scenario (``info["scenario"]``, ``info["scenario_name"]``, and
    ``info["scenario_seed"]`` for random draws).

    Args (keyword only; unknown names or bad values raise ValueError listing what is valid; defaults
    in :data:`DEFAULTS`):
        task: "velocity" (default) or "position" (its base law tracks the paper's run unsaturated but loses
            track on a sixth of the randomised scenarios: see docs/ENV.md).
        n: CLF power factor, even >= 2 (default 2).
        fr: combined-error cutoff f_r [Hz] (default 60 velocity, 20 position).
        sigma: CLF scale [unit of s] (default 1e5 velocity, 1e6 position; 1 = the paper's law).
        smoothing: sign(s) smoothing width [unit of s], >= 0 (default 1e3 velocity, 100 position).
        mode: "residual" (default) or "direct" (pure RL: no base current applied).
        residual_scale: current of a unit action [mA] (default: current_limit, or 10 if unlimited).
        agent_period: control periods per agent step, >= 1 (default 5: the agent acts at 4 kHz).
        control_period: h [s], in [1e-7, 1e-2] (default 5e-5).
        substeps: RK4 plant steps per control period, >= 1 (default 1).
        current_limit: |u| limit [mA] or None = unlimited (default 10).
        estimator_hz: output-derivative estimator cutoff [Hz] (default 1000, the paper's).
        estimator: how the reference model and the estimator run: "foh" (default; first-order-hold
            discretisation, O(h^2) to the paper's continuous filters), "zoh" (wave 1's zero-order hold,
            biased by O(h); kept to show the effect) or "analog" (continuous filters integrated with the
            plant). See docs/MODEL.md, "Digital filters".
        scenario: "random" (default; the training distribution of :mod:`ehss_gym.core.scenarios`), "paper",
            or a pinned :class:`ehss_gym.Scenario` whose controller fields equal this env's
            (``env.unwrapped.scenario_template.replace(...)``). ``reset(options={"scenario": ...})``
            overrides it for one episode (also accepting a dict of physical fields).
        reward_weights: dict overriding any of track (1), effort (0.05), rate (0.05), tv (0), tv_u (0),
            divergence (10).
        error_scale: error scale of reward and observation [output unit] (default 0.01).
        episode_seconds: episode duration [s] for "random" and "paper" (default None: 2 s random,
            20 s paper; a pinned Scenario keeps its t_end).
        render_mode: None or "rgb_array" (a dashboard: reference vs output, error, currents, friction).

    Version history:
        v0 (ehss-gym 0.1): first release. Before release the defaults moved to the reproduction
        study's recommendation (``ehss reproduce``: h = 30 us, smoothing 100 for velocity; they were
        50 us and 0); then, when the derivative estimator's O(h) bias was fixed (``estimator="foh"``;
        wave 1's scheme is ``"zoh"``), to the study's recommendation on the corrected loop: h = 50 us,
        f_r = 60 Hz and smoothing 1e3 (velocity), f_r = 20 Hz, sigma = 1e6, smoothing 100 and a 1 kHz
        estimator (position). Policies record every setting they were trained with, the estimator
        included; those of wave 1 (without it) were retrained.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}

    def __init__(self, render_mode: str | None = None, **kwargs):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}, got "
                             f"{render_mode!r}")
        self.render_mode = render_mode
        self.config = cfg = EnvConfig.from_kwargs(kwargs)
        self._lanes = Lanes(cfg, 1)
        self.observation_layout = self._lanes.layout
        D = len(self.observation_layout)
        self.observation_space = spaces.Box(-OBS_BOUND, OBS_BOUND, shape=(D,), dtype=np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)
        self._scale = cfg.residual_scale
        self._steps = 0
        self._T = 0
        self._n_clipped = 0
        self._ready = False
        self._hist: list | None = None
        self.scenario: Scenario | None = None

    @property
    def scenario_template(self) -> Scenario:
        """A Scenario with this env's controller settings; ``.replace(...)`` it to pin an episode."""
        return self._lanes.template

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        lanes = self._lanes
        sc, info = lanes.draw(0, self.config, self.np_random, options)
        lanes.load(0, sc)
        lanes.observe([0])
        self.scenario = sc
        self._T = int(lanes.T[0])
        self._steps = 0
        self._n_clipped = 0
        self._ready = True
        if self.render_mode == "rgb_array":
            self._hist = []
            self._record()
        return lanes.obs[0].copy(), info

    def step(self, action):
        if not self._ready:
            raise RuntimeError("call reset() before step()")
        if type(action) is np.ndarray and action.shape == (1,):  # fast path
            v = float(action[0])
            if v != v:
                raise ValueError("action is NaN; actions must be numbers in [-1, 1] (out-of-range values are clipped)")
        else:
            v = parse_action_scalar(action)
        clipped = v > 1.0 or v < -1.0
        if clipped:
            v = 1.0 if v > 1.0 else -1.0
            self._n_clipped += 1
        lanes = self._lanes
        lanes.u_res[0] = v * self._scale
        advance(*lanes._args)
        self._steps += 1
        terminated = not lanes.run[0]
        truncated = not terminated and self._steps >= self._T
        # Python floats in two list conversions of pre-made row views (numpy scalar reads cost ~0.1 us each)
        i = lanes.info_ok0.tolist()
        st = lanes.tail0.tolist()
        n = st[S_N]
        info = {"t": i[L.I_T], "e": i[L.I_E], "s": i[L.I_S], "V": i[L.I_V], "u_base": i[L.I_UBASE],
                "u_residual": i[L.I_URES], "u_applied": i[L.I_UAPP], "saturated": i[L.I_SAT] > 0.0,
                "sat_fraction": st[S_SAT] / n if n > 0 else 0.0, "friction_torque": i[L.I_TF],
                "clipped": clipped, "n_clipped": self._n_clipped, "diverged": terminated}
        if terminated or truncated:
            self._ready = False
            m = lanes.metrics(0)
            info["metrics"] = m
            if terminated:
                info["divergence_reason"] = m["divergence_reason"]
                info["t_diverged"] = m["t_diverged"]
        if self._hist is not None:
            self._record()
        return lanes.obs0.copy(), st[F_REW - F_STATS], terminated, truncated, info

    # --- rendering ---------------------------------------------------------------------------------

    def _record(self):
        i = self._lanes.info_ok[0]
        self._hist.append((i[L.I_T], i[L.I_YE], i[L.I_YD], i[L.I_E], i[L.I_UAPP], i[L.I_UBASE], i[L.I_URES],
                           i[L.I_TF]))

    def render(self):
        """An RGB dashboard (H, W, 3) uint8 of the episode so far, or None without render_mode."""
        if self.render_mode is None:
            gym.logger.warn("render() called without render_mode; create the env with render_mode='rgb_array'")
            return None
        return render_dashboard(np.array(self._hist or [(0.0,) * 8]), self.config, self.scenario)

    def close(self):
        self._hist = None


def render_dashboard(h: np.ndarray, cfg: EnvConfig, sc: Scenario | None, size=(6.4, 6.4), dpi=80) -> np.ndarray:
    """Draw (t, y, y_d, e, u_applied, u_base, u_res, friction) rows as a four-panel RGB image."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    unit = "rad/s" if cfg.task == "velocity" else "rad"
    fig = Figure(figsize=size, dpi=dpi)
    canvas = FigureCanvasAgg(fig)
    ax = fig.subplots(4, 1, sharex=True)
    t = h[:, 0]
    ax[0].plot(t, h[:, 2], "k--", lw=1, label="reference")
    ax[0].plot(t, h[:, 1], lw=1, label="output")
    ax[0].set_ylabel(unit)
    ax[0].legend(loc="upper right", fontsize=7)
    ax[1].plot(t, h[:, 3], lw=0.8)
    ax[1].set_ylabel(f"error [{unit}]")
    ax[2].plot(t, h[:, 4], lw=0.8, label="applied")
    ax[2].plot(t, h[:, 5], lw=0.6, label="base law")
    ax[2].plot(t, h[:, 6], lw=0.6, label="residual")
    ax[2].set_ylabel("u [mA]")
    ax[2].legend(loc="upper right", fontsize=7)
    ax[3].plot(t, h[:, 7], lw=1)
    ax[3].set_ylabel("friction [N m]")
    ax[3].set_xlabel("time [s]")
    name = sc.reference.description if sc is not None else ""
    fig.suptitle(f"EHSSTracking-v0 {cfg.task}/{cfg.mode}, n={cfg.n}  {name}", fontsize=8)
    fig.tight_layout()
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[:, :, :3].copy()


__all__ = ["EHSSTrackingEnv", "EnvConfig", "EnvDefaults", "TaskDefaults", "DEFAULTS", "Lanes", "advance",
           "advance_chunks", "observation_layout", "decode_observation", "symlog_inverse", "OBS_BOUND"]


ENV_ID = "EHSSTracking-v0"
if ENV_ID not in gym.registry:
    gym.register(ENV_ID, entry_point="ehss_gym.envs.env:EHSSTrackingEnv",
                 vector_entry_point="ehss_gym.envs.vector:EHSSTrackingVectorEnv")
