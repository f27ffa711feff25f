"""Every default of ``EHSSTracking-v0`` and the one validated record of an env's settings (:class:`EnvConfig`).

The defaults are the reproduction study's recommendation (``reports/paper/recommended_defaults.json``, made by
``ehss reproduce``; a test checks that :data:`DEFAULTS` restate it); the evidence is in docs/ENV.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ehss_gym.core import layout as L
from ehss_gym.core.scenarios import PHYSICAL_FIELDS, controller_mismatch, paper_scenario
from ehss_gym.core.sim import TASKS, Scenario
from ehss_gym.core.validate import check_choice, check_even_n, check_finite, check_int, check_positive


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
        lost_track: lost-track bound as a multiple of the reference's amplitude (see ``Scenario.lost_track``).
        terminate_on_lost_track: end an episode (``terminated=True``) once it has lost track.
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
    lost_track: float = 1.0
    terminate_on_lost_track: bool = False
    velocity: TaskDefaults = field(default_factory=lambda: TaskDefaults(
        fr=60.0, sigma=1e5, smoothing=1e3, estimator_hz=1000.0, error_scale=1e-2))
    position: TaskDefaults = field(default_factory=lambda: TaskDefaults(
        fr=20.0, sigma=1e6, smoothing=100.0, estimator_hz=1000.0, error_scale=1e-2))


DEFAULTS = EnvDefaults()
MODES = ("residual", "direct")
SCENARIOS = ("random", "paper")
REWARD_KEYS = ("track", "effort", "rate", "tv", "tv_u", "divergence")
# settings whose default depends on the task (residual_scale: on the current limit); None selects that default
TASK_DEPENDENT = ("fr", "sigma", "smoothing", "estimator_hz", "error_scale", "residual_scale")


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
    lost_track: float | None = DEFAULTS.lost_track
    terminate_on_lost_track: bool = DEFAULTS.terminate_on_lost_track

    KEYS = ("task", "n", "fr", "sigma", "smoothing", "mode", "residual_scale", "agent_period", "control_period",
            "substeps", "current_limit", "estimator_hz", "estimator", "scenario", "reward_weights", "error_scale",
            "episode_seconds", "lost_track", "terminate_on_lost_track")

    @classmethod
    def from_kwargs(cls, kwargs: dict) -> EnvConfig:
        """Validate keyword arguments; unknown names or bad values raise ValueError listing what is valid."""
        unknown = sorted(set(kwargs) - set(cls.KEYS))
        if unknown:
            raise ValueError(f"unknown keyword argument(s) {unknown}; valid: {list(cls.KEYS) + ['render_mode']}")
        d = DEFAULTS
        task = check_choice("task", kwargs.get("task", "velocity"), tuple(TASKS))
        td: TaskDefaults = getattr(d, task)
        mode = check_choice("mode", kwargs.get("mode", d.mode), MODES)
        n = kwargs.get("n", d.n)
        n = check_even_n(n)
        fr = check_positive("fr", kwargs.get("fr", td.fr))
        sigma = check_positive("sigma", kwargs.get("sigma", td.sigma))
        smoothing = check_finite("smoothing", kwargs.get("smoothing", td.smoothing), low=0.0)
        limit = kwargs.get("current_limit", d.current_limit)
        if limit is not None:
            limit = check_positive("current_limit", limit)
        scale = kwargs.get("residual_scale")
        if scale is None:
            scale = d.residual_scale if limit is None else limit
        scale = check_positive("residual_scale", scale)
        agent_period = check_int("agent_period", kwargs.get("agent_period", d.agent_period), 1)
        h = check_finite("control_period", kwargs.get("control_period", d.control_period), low=1e-7, high=1e-2)
        substeps = check_int("substeps", kwargs.get("substeps", d.substeps), 1)
        est = check_positive("estimator_hz", kwargs.get("estimator_hz", td.estimator_hz))
        scheme = check_choice("estimator", kwargs.get("estimator", d.estimator), L.ESTIMATORS)
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
        err = check_positive("error_scale", kwargs.get("error_scale", td.error_scale))
        eps = kwargs.get("episode_seconds")
        if eps is not None:
            eps = check_finite("episode_seconds", eps, low=h * agent_period)
        lost = kwargs.get("lost_track", d.lost_track)
        if lost is not None:
            lost = check_positive("lost_track", lost)
        stop_lost = kwargs.get("terminate_on_lost_track", d.terminate_on_lost_track)
        if not isinstance(stop_lost, (bool, np.bool_)):
            raise ValueError(f"terminate_on_lost_track must be True or False, got {stop_lost!r}")
        cfg = cls(task=task, n=int(n), fr=fr, sigma=sigma, smoothing=smoothing, mode=mode, residual_scale=scale,
                  agent_period=agent_period, control_period=h, substeps=substeps, current_limit=limit,
                  estimator_hz=est, estimator=scheme, scenario=scenario, reward_weights=rw, error_scale=err,
                  episode_seconds=eps, lost_track=lost, terminate_on_lost_track=bool(stop_lost))
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
                                       estimator_hz=self.estimator_hz, estimator=self.estimator,
                                       lost_track=self.lost_track))

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

