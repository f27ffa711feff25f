"""Every default of ``EHSSTracking-v0`` and the one validated record of an env's settings (:class:`EnvConfig`).

The env's settings are the loop settings of :class:`ehss_gym.core.settings.Scenario` (:data:`LOOP_KEYS`; a setting
without an env default here takes the Scenario's) and the env's own (:data:`ENV_KEYS`: the plant and the law settings
tuned for it, mode, reward, episode). The defaults, all for Table I's plant (another plant's come from its file and
from ``ehss baselines --plant FILE``: :mod:`ehss_gym.core.rig`, :mod:`ehss_gym.envs.law_table`), are the
recommendation of three studies, restated here (tests check each): the baselines' tuning
(``reports/baselines/tuned.json``, made by ``ehss baselines``: per task and n the CLF law's sigma, f_r, smoothing
width and boundary-layer gain, :data:`LAW_DEFAULTS`, and by its written rule the default n), the reproduction study
(``reports/paper/recommended_defaults.json``, made by ``ehss reproduce``: period, substeps, current limit, the SVF
cutoff) and the noise study (``reports/noise/recommended.json``, made by ``ehss noise``: per task the estimator, the
law, the observer bandwidth and the reference shaper, and each other law's sigma). The bumpless start is the
evaluation ruler's choice (:data:`BUMPLESS_DEFAULT`). The evidence is in docs/ENV.md.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, fields

import numpy as np

from ehss_gym.core.registry import ESTIMATORS, LAWS, entry, names
from ehss_gym.core.rig import TABLE_I, Rig, as_rig
from ehss_gym.core.scenarios import (
    DEFAULT_DISTRIBUTION,
    Distribution,
    controller_mismatch,
    paper_scenario,
    unmodelled_distribution,
)
from ehss_gym.core.settings import LOOP_SETTINGS, PHYSICAL_FIELDS, TASKS, Scenario
from ehss_gym.core.validate import check_bool, check_choice, check_finite, check_int, check_positive

from .actions import ACTIONS, action_mode
from .law_table import LawTable, as_law_table

# The bumpless start (the reference model starts at the measured output and its estimated derivatives, as servo
# drives do) is the default of both tasks because of the evaluation's ruler, not the noise study: with the paper's
# start (the reference model at its steady state for r(0), the plant at rest) e(0) = -r(0), and the first 0.2 s held
# 96.5 % (velocity) and 100 % (position) of the held-out suite's pooled squared error. The response to such a jump
# is measured on its own, by the step suite of `ehss evaluate`; its paper suite keeps the paper's start.
BUMPLESS_DEFAULT = True
# current_limit="rated" (the env's default): the plant's rated current (Table I: 10 mA, EnvDefaults.current_limit)
RATED = "rated"


@dataclass(frozen=True)
class LawSettings:
    """The CLF law's settings that ``ehss baselines`` tunes per task and n.

    Attributes:
        sigma: CLF scale sigma [unit of s].
        fr: combined-error cutoff f_r [Hz].
        smoothing: sign(s) smoothing width w [unit of s] (0 = the plain law).
        layer_gain: adaptive boundary-layer gain [-] (0 = the fixed width ``smoothing``).
    """

    sigma: float
    fr: float
    smoothing: float
    layer_gain: float


LAW_KEYS = tuple(f.name for f in fields(LawSettings))
# The CLF law's defaults per task and n: the tuned values of `ehss baselines` (reports/baselines/tuned.json;
# tests/test_baselines.py checks this table against it). An env made with n = k and none of these settings given
# takes row k (an n without a row takes the task's default n's row); the task's defaults are its default n's row
# (DEFAULT_N, the written rule's outcome: the lowest tuning objective, a smaller n kept unless a larger one is lower
# by more than 2 %).
LAW_DEFAULTS: dict[str, dict[int, LawSettings]] = {
    "velocity": {
        2: LawSettings(sigma=80584.21877614819, fr=99.16136483369311, smoothing=107.46078283213177,
                       layer_gain=11.772569275453606),
        4: LawSettings(sigma=165481.70999431814, fr=127.5608767778436, smoothing=220.67340690845896,
                       layer_gain=4.964451299829543),
        6: LawSettings(sigma=165481.70999431814, fr=129.8763263152423, smoothing=220.67340690845896,
                       layer_gain=4.964451299829543),
    },
    "position": {
        2: LawSettings(sigma=133352.1432163324, fr=54.44973030087656, smoothing=39.24189758484536,
                       layer_gain=7.374732206760591),
        4: LawSettings(sigma=14330.125702369629, fr=60.0, smoothing=165.48170999431815,
                       layer_gain=3.59125509148719),
        6: LawSettings(sigma=10746.078283213177, fr=53.40287390764913, smoothing=42.169650342858226,
                       layer_gain=4.964451299829544),
    },
}
DEFAULT_N = {"velocity": 2, "position": 2}


def law_defaults(task: str, n) -> LawSettings:
    """The CLF law's default settings for ``task`` at power factor ``n`` (the default n's for an n without a row)."""
    rows = LAW_DEFAULTS[task]
    try:
        return rows.get(n, rows[DEFAULT_N[task]])
    except TypeError:  # an unhashable n: the env's validation names it
        return rows[DEFAULT_N[task]]


def _task_law(task: str) -> dict:
    """The task's default n's row of LAW_DEFAULTS as TaskDefaults keyword arguments."""
    ls = LAW_DEFAULTS[task][DEFAULT_N[task]]
    return {k: getattr(ls, k) for k in LAW_KEYS}


@dataclass(frozen=True)
class TaskDefaults:
    """Per-task defaults (the CLF law's at the task's default n; another n takes its row of :data:`LAW_DEFAULTS`).

    Attributes:
        fr: combined-error cutoff f_r [Hz].
        sigma: CLF scale sigma of the default law [unit of s].
        smoothing: sign(s) smoothing width w [unit of s].
        estimator_hz: cutoff of the paper's state-variable filter [Hz].
        error_scale: tracking-error scale of the reward and observation [output unit].
        estimator: output-derivative estimator (a row of :data:`ehss_gym.core.registry.ESTIMATORS`).
        law: CLF law (a row of :data:`ehss_gym.core.registry.LAWS`).
        sigma_by_law: (law, sigma) pairs: the sigma a law gets when the law is chosen and sigma is not.
        observer_hz: error bandwidth of the "eso" observer [Hz].
        layer_gain: adaptive boundary-layer gain (0 = the fixed width ``smoothing``).
        bumpless: the reference model starts at the measured output.
        ref_accel: acceleration bound of the reference shaper [rad/s^2] (position; 0 = none).
    """

    fr: float
    sigma: float
    smoothing: float
    estimator_hz: float
    error_scale: float
    estimator: str = "foh"
    law: str = "sontag"
    sigma_by_law: tuple = ()
    observer_hz: float = 200.0
    layer_gain: float = 0.0
    bumpless: bool = False
    ref_accel: float = 0.0

    def sigma_for(self, law: str) -> float:
        """The default sigma of ``law`` (the task's sigma for its own default law)."""
        return dict(self.sigma_by_law).get(law, self.sigma) if law != self.law else self.sigma


@dataclass(frozen=True)
class EnvDefaults:
    """Every default of the env in one place.

    Attributes:
        n: CLF power factor.
        mode: "residual" or "direct".
        current_limit: valve current limit [mA] of Table I's loop (its plant file's rated current; another plant's
            rated current replaces it unless a limit is given).
        control_period: controller sample time h [s].
        substeps: RK4 plant steps per control period.
        agent_period: control periods per agent step.
        residual_scale: current of a unit action [mA] when current_limit is None (else the current limit).
        pressure_domain: the controller evaluates its model at |x3| <= pressure_domain * P_s (None = anywhere).
        dob_hz: cutoff of the disturbance observer on the combined error [Hz]; 0 = off.
        scenario: "random" or "paper".
        reward_weights: track, effort, rate, tv, tv_u, divergence, class, saturation, physical weights.
        memory_tau: time constant [s] of the observation's filtered error integral (with the action of the step
            before last: the memory features); None = no memory features (the observation as before).
        lost_track: lost-track bound as a multiple of the reference's amplitude (see ``Scenario.lost_track``).
        terminate_on_lost_track: end an episode (``terminated=True``) once it has lost track.
        unmodelled_effects: "random" episodes draw the valve and sensor effects the law's model leaves out
            (:data:`ehss_gym.core.scenarios.UNMODELLED_DISTRIBUTION`).
        unmodelled_share: with ``unmodelled_effects``, the share of the episodes that have them (the others none).
        action: what the agent's action does, a row of :data:`ehss_gym.envs.actions.ACTIONS`.
        velocity, position: per-task defaults.
    """

    n: int = DEFAULT_N["velocity"]  # the rule gave both tasks the same n (tests/test_baselines.py checks it)
    mode: str = "residual"
    current_limit: float = 10.0
    control_period: float = 5e-5
    substeps: int = 1
    agent_period: int = 5
    residual_scale: float = 10.0
    pressure_domain: float | None = 0.95
    dob_hz: float = 0.0
    scenario: str = "random"
    reward_weights: tuple = (("track", 1.0), ("effort", 0.05), ("rate", 0.05), ("tv", 0.0), ("tv_u", 0.0),
                             ("divergence", 10.0), ("class", 0.0), ("saturation", 0.0), ("physical", 0.0))
    memory_tau: float | None = None
    lost_track: float = 1.0
    terminate_on_lost_track: bool = False
    unmodelled_effects: bool = False
    unmodelled_share: float = 1.0
    action: str = "current"
    # Per task, the noise study's choice (reports/noise/recommended.json; tests/test_noise.py checks it): velocity the
    # paper's SVF with Sontag, position the 1 kHz observer with Sontag and the 100 rad/s^2 reference shaper. The law's
    # sigma, f_r, smoothing and boundary layer are the baselines' tuning (LAW_DEFAULTS). The bumpless start is the
    # ruler's choice, BUMPLESS_DEFAULT (the noise study kept the paper's start: it removes no lost episode, its
    # start-up rule's criterion).
    velocity: TaskDefaults = field(default_factory=lambda: TaskDefaults(
        **_task_law("velocity"), estimator_hz=1000.0, error_scale=1e-2, estimator="foh", law="sontag",
        sigma_by_law=(("lin-sontag", 3e6),), observer_hz=200.0, bumpless=BUMPLESS_DEFAULT, ref_accel=0.0))
    position: TaskDefaults = field(default_factory=lambda: TaskDefaults(
        **_task_law("position"), estimator_hz=1000.0, error_scale=1e-2, estimator="eso", law="sontag",
        sigma_by_law=(("lin-sontag", 1e7),), observer_hz=1000.0, bumpless=BUMPLESS_DEFAULT, ref_accel=100.0))


DEFAULTS = EnvDefaults()
MODES = ("residual", "direct")
SCENARIOS = ("random", "paper")
REWARD_KEYS = ("track", "effort", "rate", "tv", "tv_u", "divergence", "class", "saturation", "physical")
# Loop settings the env keeps at the Scenario's defaults (not keyword arguments of the env).
FIXED_LOOP = ("ref_model_hz", "omega_max", "pressure_bound")
# The env's settings: the loop settings it exposes, then its own.
LOOP_KEYS = tuple(k for k in LOOP_SETTINGS if k not in FIXED_LOOP)
ENV_KEYS = ("plant", "law_settings", "mode", "residual_scale", "agent_period", "scenario", "reward_weights",
            "error_scale", "episode_seconds", "terminate_on_lost_track", "unmodelled_effects", "unmodelled_share",
            "memory_tau", "action", "action_bound")
# What a policy acts in (an exported policy pins each): everything but the episode's choice and when it ends, and the
# plant (the rig an exported policy was trained on is recorded when it was given: agents.specs.resolved_env_kwargs).
POLICY_KEYS = tuple(k for k in LOOP_KEYS + ENV_KEYS
                    if k not in ("scenario", "episode_seconds", "lost_track", "terminate_on_lost_track",
                                 "unmodelled_effects", "unmodelled_share", "plant", "law_settings"))
# Settings whose default depends on the task (residual_scale: on the current limit, sigma: on the law too); None
# selects that default.
TASK_DEPENDENT = tuple(f.name for f in fields(TaskDefaults) if f.name != "sigma_by_law") + ("residual_scale",)
# Settings for which None is a value (no current limit, the model at the measured pressure, no lost-track detection,
# the episode's own duration); for the others a keyword argument None selects the default.
NONE_IS_A_VALUE = tuple(f.name for f in fields(Scenario) if f.name in LOOP_KEYS and "None" in str(f.type)) + (
    "episode_seconds", "memory_tau")
# The law's add-ons (off by default): the disturbance observer and the compensators of the unmodelled valve and
# sensors. A loop with one of them on is today's loop with an add-on (the scripted dob-n2 and dcomp-n2, a residual on
# top of them), and the ruler's reference law has them off.
ADDON_KEYS = ("dob_hz", "reference_delay", "inverse_threshold", "inverse_hysteresis")


def reference_law_kwargs(env_kwargs: dict, addons: dict | None = None) -> dict:
    """The env settings of the n = 2 law (a zero residual) in the loop of ``env_kwargs``: its add-ons
    (:data:`ADDON_KEYS`) and its action mode left out (every mode's zero action is the base law, and a mode may need
    an add-on), then ``addons`` put in (None: none, the ruler's reference law)."""
    kw = {k: v for k, v in env_kwargs.items() if k not in ADDON_KEYS + ("action", "action_bound")}
    return {**kw, **(addons or {}), "mode": "residual", "n": 2}
# The loop of the first policies of release 0.1: the settings added since (the law, the adaptive boundary layer, the
# bumpless start, the reference shaper, the model's pressure domain, the disturbance observer) at the values that
# reproduce the loop before them. A policy whose recorded settings lack them was trained in that loop and acts in it
# (:func:`in_legacy_loop`).
LEGACY_LOOP = {"law": "sontag", "layer_gain": 0.0, "bumpless": False, "ref_accel": 0.0, "pressure_domain": None,
               "dob_hz": 0.0, "lyapunov_kappa": None}


def in_legacy_loop(env_kwargs: dict) -> dict:
    """The env settings a recorded policy acts in: ``env_kwargs`` with the settings of :data:`LEGACY_LOOP` it lacks
    at their legacy values, so that a change of the env's defaults does not change the loop it was trained in."""
    return {**LEGACY_LOOP, **env_kwargs}


@dataclass(frozen=True)
class EnvConfig:
    """Validated settings of an :class:`~ehss_gym.envs.env.EHSSTrackingEnv` (its docstring gives each).

    The loop settings (:data:`LOOP_KEYS`) are those of :attr:`loop`, a :class:`~ehss_gym.core.settings.Scenario`
    with the paper's episode (:meth:`template`), and read as attributes (``cfg.sigma``); the env's own are fields.
    """

    loop: Scenario
    mode: str
    residual_scale: float
    agent_period: int
    scenario: object
    reward_weights: dict
    error_scale: float
    episode_seconds: float | None
    terminate_on_lost_track: bool = DEFAULTS.terminate_on_lost_track
    unmodelled_effects: bool = DEFAULTS.unmodelled_effects
    unmodelled_share: float = DEFAULTS.unmodelled_share
    memory_tau: float | None = DEFAULTS.memory_tau
    action: str = DEFAULTS.action
    action_bound: float | None = None
    plant: Rig = TABLE_I
    law_settings: LawTable | None = None

    KEYS = LOOP_KEYS + ENV_KEYS

    def __getattr__(self, name: str):
        # only for names that are not fields: the loop settings, from the template
        if name in LOOP_KEYS:
            return getattr(object.__getattribute__(self, "loop"), name)
        raise AttributeError(f"{type(self).__name__} has no attribute {name!r}")

    @classmethod
    def from_kwargs(cls, kwargs: dict) -> EnvConfig:
        """Validate keyword arguments; unknown names or bad values raise ValueError listing what is valid."""
        unknown = sorted(set(kwargs) - set(cls.KEYS))
        if unknown:
            raise ValueError(f"unknown keyword argument(s) {unknown}; valid: {list(cls.KEYS) + ['render_mode']}")
        d = DEFAULTS
        rig = plant_of(kwargs.get("plant"))
        table = law_table_of(kwargs.get("law_settings"))
        task = check_choice("task", kwargs.get("task", "velocity"), tuple(TASKS))
        td: TaskDefaults = getattr(d, task)
        mode = check_choice("mode", kwargs.get("mode", d.mode), MODES)
        law = check_choice("law", kwargs.get("law", td.law), names(LAWS))
        loop = {k: kwargs[k] if k in kwargs else _default(k, td, d) for k in LOOP_KEYS}
        # the law's settings not given: the row of the env's n (tuned per n); another law's sigma: its own
        per_n = law_row(table, task, loop["n"])
        loop.update({k: per_n[k] for k in LAW_KEYS if k not in kwargs})
        if "sigma" not in kwargs and law != td.law:
            loop["sigma"] = td.sigma_for(law)
        loop.update(task=task, law=law)
        if isinstance(loop["current_limit"], str) and loop["current_limit"] == RATED:
            loop["current_limit"] = rig.rated_current
        elif "current_limit" not in kwargs:
            loop["current_limit"] = rig.rated_current  # Table I's: EnvDefaults.current_limit
        # the env's ranges beyond the Scenario's own checks
        loop["control_period"] = check_finite("control_period", loop["control_period"], low=1e-7, high=1e-2)
        loop["substeps"] = check_int("substeps", loop["substeps"], 1)
        # every loop setting checked, with the core record's messages; the template carries the rig
        template = paper_scenario(Scenario(**loop, plant=rig.plant, model=rig.model, rated_current=rig.rated_current))
        limit = template.current_limit
        scale = kwargs.get("residual_scale")
        if scale is None:
            scale = d.residual_scale if limit is None else limit
        scale = check_positive("residual_scale", scale)
        agent_period = check_int("agent_period", kwargs.get("agent_period", d.agent_period), 1)
        cfg = cls(loop=template, mode=mode, residual_scale=scale, agent_period=agent_period, plant=rig,
                  law_settings=table,
                  **_episode_settings(kwargs, td, d, template.control_period * agent_period),
                  **_action_settings(kwargs, d, template, mode))
        if isinstance(cfg.scenario, Scenario):
            cfg.check_pinned(cfg.scenario)
        return cfg

    @property
    def order(self) -> int:
        return TASKS[self.task]

    @property
    def agent_dt(self) -> float:
        """Duration of one agent step [s]."""
        return self.agent_period * self.control_period

    def distribution(self) -> Distribution:
        """The distribution "random" episodes are drawn from: the unmodelled effects on ``unmodelled_share`` of them
        with ``unmodelled_effects``, else none."""
        return unmodelled_distribution(self.unmodelled_share) if self.unmodelled_effects else DEFAULT_DISTRIBUTION

    def template(self) -> Scenario:
        """A Scenario with these controller settings (its physical fields are the paper's run on the env's plant, with
        the controller's model of it)."""
        return self.loop

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


_SCENARIO_DEFAULTS = {f.name: f.default for f in fields(Scenario)}


class PlantWarning(UserWarning):
    """The CLF law's settings were not tuned for the env's plant (Table I's on another rig, or a file tuned on
    another plant): the loop may saturate or chatter; ``ehss baselines --plant FILE`` tunes them."""


def law_table_of(value) -> LawTable | None:
    """The env's law table from its ``law_settings`` setting (None: the built-in per-n table, Table I's tuning);
    ValueError naming the setting otherwise."""
    try:
        return as_law_table(value)
    except ValueError as exc:
        msg = str(exc)
        raise ValueError(msg if msg.startswith("law") else f"law_settings: {msg}") from None


def law_row(table: LawTable | None, task: str, n) -> dict:
    """The CLF law's settings (sigma, f_r, smoothing, layer_gain) of ``task`` at ``n``: the law table's row, or the
    built-in :data:`LAW_DEFAULTS` (Table I's tuning) without one."""
    if table is None:
        ls = law_defaults(task, n)
        return {k: getattr(ls, k) for k in LAW_KEYS}
    try:
        return table.row(task, n)
    except ValueError as exc:
        raise ValueError(f"law_settings: {exc}") from None


def untuned_note(cfg: EnvConfig, given) -> str | None:
    """Why the CLF law's settings of ``cfg`` were not tuned for its plant (Table I's rows on another rig, or a law
    table tuned on another plant), or None; ``given``: the settings given explicitly (all four law settings given:
    None). The direct mode, where the law's current is not applied, has no such note."""
    if all(k in given for k in LAW_KEYS) or cfg.mode == "direct":
        return None
    rig, table = cfg.plant, cfg.law_settings
    if table is None and not rig.is_table_i:
        return (f"the CLF law's settings are those tuned for Table I, and the plant is {rig.label}: tune them for it "
                "with `ehss baselines --plant FILE` and pass its law_settings.json (law_settings=..., --law-settings)")
    if table is not None and table.plant_hash and table.plant_hash != rig.hash:
        return f"the law settings {table.source} were tuned on {table.plant_label}, and the plant is {rig.label}"
    return None


def warn_untuned(cfg: EnvConfig, given) -> None:
    """A :class:`PlantWarning` with :func:`untuned_note`, if any (the envs' constructors call it)."""
    note = untuned_note(cfg, given)
    if note:
        warnings.warn(note, PlantWarning, stacklevel=3)


def plant_of(value) -> Rig:
    """The env's rig from its ``plant`` setting (:func:`ehss_gym.core.rig.as_rig`: None = Table I, a Rig, a
    PlantParams, a dict, a TOML file path or a shipped plant's name); ValueError naming the setting otherwise."""
    try:
        return as_rig(value)
    except ValueError as exc:
        msg = str(exc)
        raise ValueError(msg if msg.startswith("plant") else f"plant: {msg}") from None


def _default(key: str, td: TaskDefaults, d: EnvDefaults):
    """The env's default of loop setting ``key``: the task's, the env's, else the Scenario's."""
    for where in (td, d):
        if key in {f.name for f in fields(where)}:
            return getattr(where, key)
    return _SCENARIO_DEFAULTS[key]


def _episode_settings(kwargs: dict, td: TaskDefaults, d: EnvDefaults, agent_dt: float) -> dict:
    """The episode's choice, the reward and the end of an episode, validated."""
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
        eps = check_finite("episode_seconds", eps, low=agent_dt)
    stop_lost = kwargs.get("terminate_on_lost_track", d.terminate_on_lost_track)
    if not isinstance(stop_lost, (bool, np.bool_)):
        raise ValueError(f"terminate_on_lost_track must be True or False, got {stop_lost!r}")
    unmodelled = check_bool("unmodelled_effects", kwargs.get("unmodelled_effects", d.unmodelled_effects))
    share = check_finite("unmodelled_share", kwargs.get("unmodelled_share", d.unmodelled_share), low=0.0, high=1.0,
                         low_open=True)
    tau = kwargs.get("memory_tau", d.memory_tau)
    if tau is not None:
        tau = check_finite("memory_tau", tau, low=agent_dt)
    return {"scenario": scenario, "reward_weights": rw, "error_scale": err, "episode_seconds": eps,
            "terminate_on_lost_track": bool(stop_lost), "unmodelled_effects": unmodelled, "unmodelled_share": share,
            "memory_tau": tau}


def _action_settings(kwargs: dict, d: EnvDefaults, template: Scenario, mode: str) -> dict:
    """The action mode and its bound (None: the mode's default for the task), validated."""
    row = action_mode(kwargs.get("action", d.action))
    bound = kwargs.get("action_bound")
    if bound is None:
        bound = row.default_bound(template.task)
    elif not row.bound:
        with_bound = [r.name for r in ACTIONS if r.bound]
        raise ValueError(f"action_bound applies to the actions {with_bound} (None: the action's default); action "
                         f"{row.name!r} has none ({row.source}), got {bound!r}")
    else:
        bound = check_positive("action_bound", bound)
    if row.resense and mode != "residual":
        raise ValueError(f"action {row.name!r} acts through the law: it needs mode 'residual', got mode {mode!r}")
    if row.shift and entry(ESTIMATORS, template.estimator).analog:
        raise ValueError(f"action {row.name!r} shifts the law's digital reference model: it needs a digital estimator "
                         f"(not {template.estimator!r})")
    if row.compensators and not (template.reference_delay > 0.0 or template.inverse_threshold > 0.0
                                 or template.inverse_hysteresis > 0.0):
        raise ValueError(f"action {row.name!r} scales the loop's compensators: it needs reference_delay, "
                         f"inverse_threshold or inverse_hysteresis > 0 (all are 0)")
    return {"action": row.name, "action_bound": bound}


# The unit of each setting in the defaults table (U = the task's output unit: rad/s velocity, rad position; "" for a
# choice or a flag).
SETTING_UNITS = {
    "n": "-", "fr": "Hz", "sigma": "unit of s", "smoothing": "unit of s",
    "current_limit": "mA (None: unlimited; default: the plant's rated current)",
    "control_period": "s", "substeps": "RK4 steps per period", "estimator_hz": "Hz", "estimator": "",
    "observer_hz": "Hz",
    "law": "", "layer_gain": "-", "bumpless": "", "ref_accel": "rad/s^2 (0: none)", "pressure_domain": "x P_s",
    "lost_track": "x reference amplitude", "dob_hz": "Hz (0: off)",
    "lyapunov_kappa": "- (None: off)", "reference_delay": "control samples (0: off)",
    "inverse_threshold": "% of rated current (0: none)", "inverse_hysteresis": "% of rated current (0: none)",
    "plant": "TOML file, dict, PlantParams or Rig", "law_settings": "JSON file or dict (None: Table I's tuning)",
    "mode": "", "residual_scale": "mA", "agent_period": "control periods",
    "scenario": "", "reward_weights": "-", "error_scale": "U", "episode_seconds": "s (None: 2 s random, 20 s paper)",
    "terminate_on_lost_track": "", "unmodelled_effects": "", "unmodelled_share": "- (share of episodes)",
    "memory_tau": "s (None: no memory features)",
    "action": "", "action_bound": "the action's unit (None: none)",
}


def _cell(v) -> str:
    """A default as the table shows it."""
    if v is None or isinstance(v, (bool, np.bool_, int)):
        return str(v)
    if isinstance(v, Rig):
        return v.name
    if isinstance(v, float):
        if v != 0.0 and not 1e-3 <= abs(v) < 1e4:  # 1e5, 5e-5: the way the docs write them
            m, e = f"{v:.6e}".split("e")
            return f"{m.rstrip('0').rstrip('.')}e{int(e)}"
        return f"{v:g}"
    if isinstance(v, str):
        return f'`"{v}"`'
    return str(v)


def defaults_table() -> str:
    """Every default a user of the env sees, per task, as a markdown table read from :class:`EnvConfig` (the one
    table README.md, docs/ENV.md and the env's docstring show; ``python -m ehss_gym.envs.defaults --write``
    rewrites them). Rows for a law with its own default sigma and for an n whose defaults differ from the default
    n's follow."""
    cfgs = {t: EnvConfig.from_kwargs({"task": t}) for t in TASKS}
    rows = ["| setting | " + " | ".join(cfgs) + " | unit |", "|---|" + "---|" * len(cfgs) + "---|"]
    for key in [k for k in LOOP_KEYS if k != "task"] + list(ENV_KEYS):
        vals = [getattr(c, key) for c in cfgs.values()]
        if isinstance(vals[0], dict):  # one row per entry (the reward weights)
            for k in vals[0]:
                rows.append(f'| `{key}["{k}"]` | ' + " | ".join(_cell(v[k]) for v in vals)
                            + f" | {SETTING_UNITS[key]} |")
            continue
        rows.append(f"| `{key}` | " + " | ".join(_cell(v) for v in vals) + f" | {SETTING_UNITS[key]} |")
    for law in names(LAWS):  # a law with its own default sigma (the others take the task's)
        sig = {t: EnvConfig.from_kwargs({"task": t, "law": law}).sigma for t in cfgs}
        if any(sig[t] != c.sigma for t, c in cfgs.items()):
            rows.append(f'| `sigma` with `law="{law}"` | ' + " | ".join(_cell(v) for v in sig.values())
                        + f" | {SETTING_UNITS['sigma']} |")
    for row in ACTIONS:  # an action with a bound: its default per task
        if row.bound:
            rows.append(f'| `action_bound` with `action="{row.name}"` | '
                        + " | ".join(_cell(row.default_bound(t)) for t in cfgs) + f" | {row.unit} |")
    for n in (4, 6):
        per_n = {t: EnvConfig.from_kwargs({"task": t, "n": n}) for t in cfgs}
        for key in (k for k in LOOP_KEYS if k not in ("task", "n")):
            if any(getattr(per_n[t], key) != getattr(cfgs[t], key) for t in cfgs):
                rows.append(f"| `{key}` with `n={n}` | " + " | ".join(_cell(getattr(per_n[t], key)) for t in cfgs)
                            + f" | {SETTING_UNITS[key]} |")
    return "\n".join(rows) + "\n"


__all__ = ["RATED", "plant_of", "law_table_of", "law_row", "PlantWarning", "untuned_note", "warn_untuned",
           "LawSettings", "LAW_KEYS", "LAW_DEFAULTS", "DEFAULT_N", "law_defaults",
           "TaskDefaults", "EnvDefaults", "DEFAULTS", "EnvConfig", "MODES", "SCENARIOS", "REWARD_KEYS", "LOOP_KEYS",
           "ENV_KEYS", "POLICY_KEYS", "ADDON_KEYS", "reference_law_kwargs", "FIXED_LOOP", "TASK_DEPENDENT",
           "NONE_IS_A_VALUE", "LEGACY_LOOP", "in_legacy_loop", "SETTING_UNITS", "defaults_table"]
