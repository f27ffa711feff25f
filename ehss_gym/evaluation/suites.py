"""Suites: the pinned physical episodes every policy of an evaluation sees, and the sizes that make them.

Per task (the physical episodes come from :mod:`ehss_gym.core.scenarios`):

- ``paper``: the paper's 20 s run (1 rad/s, 2 rad/s sine; 1.8 N*m friction from 8 s to 10 s).
- ``heldout``: ``K`` randomised episodes from :func:`ehss_gym.core.scenarios.heldout_scenarios` (seeds at
  ``HELDOUT_SEED_BASE + i`` and above, disjoint from every training seed).
- ``robustness``: two sweeps on episodes drawn from further held-out seeds (offset
  :data:`ROBUST_SEED_START`) with their noise removed and one friction event from
  :data:`SWEEP_WINDOW`: friction amplitude (plant = model; level 0 is an event of amplitude 0, so its
  disturbance window is measured as at every other level) and model mismatch (beta, J, B, c_sm, P_s
  of the true plant each scaled by 1 +- level, signs drawn per episode; friction 1.8 N*m).
- ``step``: the start-up/step suite: from rest (plant, reference model and estimator at rest, r = 0 before
  the step) a step of each amplitude of ``EvalConfig.step_amplitudes`` at :data:`STEP_TIME`, lasting
  :data:`STEP_SECONDS` of the task; no friction, no noise, plant = model.
- ``unmodelled``: ``K`` episodes of the held-out distribution (seeds at ``HELDOUT_SEED_BASE +``
  :data:`UNMODELLED_SEED_START` ``+ i``, disjoint from the other suites' and every training seed) with the valve and
  sensor effects the law's model leaves out drawn at datasheet sizes
  (:data:`ehss_gym.core.scenarios.UNMODELLED_DISTRIBUTION`: valve threshold and hysteresis, sensor delay, encoder
  quantisation; docs/MODEL.md, "Unmodelled valve and sensors").

The paper suite keeps the paper's start (:data:`SUITE_ENV`: the reference model at its steady state for r(0));
the others run at the env's default, the bumpless start.

Every suite runs on the evaluation's plant (``EvalConfig.plant``: Table I unless a plant file is given): its episodes'
plants are that rig's (the held-out and robustness mismatch drawn around it), the controller's model is the rig's, and
the valve's threshold and hysteresis in the unmodelled suite are percent of its rated current.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from ehss_gym.core.rig import Rig, as_rig
from ehss_gym.core.scenarios import (
    HELDOUT_SEED_BASE,
    PHYSICAL_FIELDS,
    UNMODELLED_DISTRIBUTION,
    heldout_scenarios,
    paper_scenario,
)
from ehss_gym.core.settings import UNITS  # task -> unit of its output y (re-exported: the report's tables use it)
from ehss_gym.core.signals import step
from ehss_gym.envs import EnvConfig
from ehss_gym.envs.config import law_table_of
from ehss_gym.envs.law_table import LawTable

TASKS = ("velocity", "position")
SUITES = ("paper", "heldout", "robustness", "step", "unmodelled")
SUITE_ENV = {"paper": {"bumpless": False}}  # env settings a suite fixes for every policy (the paper's start)
STEP_TIME = 0.1  # [s] when the step-suite reference steps from 0
STEP_AMPLITUDES = (0.2, -0.2, 0.5, -0.5, 1.0, -1.0, 1.5, -1.5)  # [output unit] the step suite's steps
STEP_SECONDS = {"velocity": 1.0, "position": 1.5}  # [s] duration of a step-suite episode per task
ROBUST_SEED_START = 1_000_000  # held-out seed offset of the robustness episodes (the heldout suite uses 0..K-1)
UNMODELLED_SEED_START = 2_000_000  # held-out seed offset of the unmodelled suite's episodes
SWEEP_WINDOW = (0.8, 1.4)  # [s] friction event of the robustness sweeps (in 2 s episodes)
SWEEP_MISMATCH_FRICTION = 1.8  # [N*m] friction amplitude during the mismatch sweep (the paper's)
MISMATCH_PARAMS = ("beta", "J", "B", "c_sm", "P_s")
NO_NOISE = (0.0, 0.0, 0.0, 0.0)  # sensor noise std of the four measured channels in the sweeps


@dataclass(frozen=True)
class EvalConfig:
    """Sizes and seeds of an evaluation.

    Attributes:
        suites: any of "paper", "heldout", "robustness", "step", "unmodelled".
        tasks: any of "velocity", "position".
        heldout_episodes: randomised held-out episodes per task (K), in the heldout suite and in the unmodelled
            suite each.
        episode_seconds: duration of held-out and robustness episodes [s].
        paper_seconds: duration of the paper run [s] (the paper: 20).
        friction_levels: friction amplitudes of the sweep [N*m] (0: an event of amplitude 0).
        mismatch_levels: relative plant-parameter deviations of the mismatch sweep (0.2 = +-20 %).
        sweep_episodes: episodes per sweep level (M).
        step_amplitudes: the step suite's step amplitudes [output unit], each non-zero.
        n_boot: bootstrap replicates.
        seed: bootstrap seed.
        chunk: episodes per job (one job = one policy run on up to ``chunk`` episodes of one suite/task).
        plant: the rig every suite runs on (:func:`ehss_gym.core.rig.as_rig`: a Rig, a plant file, ...); None =
            Table I, not given (the CSVs then carry no plant column).
        law_settings: the scripted laws' settings tuned for the plant (:mod:`ehss_gym.envs.law_table`: a
            law-settings file, its content or a LawTable); None = the env's built-in rows (Table I's tuning).
    """

    suites: tuple = SUITES
    tasks: tuple = TASKS
    heldout_episodes: int = 48
    episode_seconds: float = 2.0
    paper_seconds: float = 20.0
    friction_levels: tuple = (0.0, 0.9, 1.8, 2.7, 3.6)
    mismatch_levels: tuple = (0.0, 0.05, 0.1, 0.15, 0.2)
    sweep_episodes: int = 5
    step_amplitudes: tuple = STEP_AMPLITUDES
    n_boot: int = 2000
    seed: int = 0
    # 64: one job per policy run, task and suite of the default evaluation (its largest, robustness, has 50 episodes):
    # a vector step's Python and the policy's forward pass cost the same for 24 lanes as for 48, so fewer, larger
    # jobs are faster (the held-out suite's 2,496 episodes: 38 s against 49 s at 24, the same rows)
    chunk: int = 64
    plant: Rig | None = None
    law_settings: LawTable | None = None

    @property
    def rig(self) -> Rig:
        """The rig the suites run on (Table I if no plant was given)."""
        return as_rig(self.plant)

    def env_kwargs(self) -> dict:
        """The env settings the scripted policies of the evaluation get from it: the plant and the law settings,
        where given."""
        out = {} if self.plant is None else {"plant": self.plant}
        return out if self.law_settings is None else {**out, "law_settings": self.law_settings}

    @classmethod
    def quick(cls, **changes) -> EvalConfig:
        """The CI form: 8 held-out episodes, one episode per sweep level, the paper run cut at 12 s (friction
        8-10 s and 2 s after it), three steps, fewer bootstrap replicates.

        Args:
            **changes: fields to set on top of the quick form.
        """
        base = cls(heldout_episodes=8, paper_seconds=12.0, friction_levels=(0.0, 1.8, 3.6), mismatch_levels=(0.0, 0.2),
                   sweep_episodes=1, step_amplitudes=(0.5, -1.0, 1.5), n_boot=1000)
        return replace(base, **changes)

    def __post_init__(self):
        """Raises ValueError naming the first setting out of range."""
        bad = [s for s in self.suites if s not in SUITES]
        if bad or not self.suites:
            raise ValueError(f"suites must be a non-empty subset of {list(SUITES)}, got {list(self.suites)}")
        bad = [t for t in self.tasks if t not in TASKS]
        if bad or not self.tasks:
            raise ValueError(f"tasks must be a non-empty subset of {list(TASKS)}, got {list(self.tasks)}")
        for name in ("heldout_episodes", "sweep_episodes", "chunk"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {v!r}")
        for name in ("episode_seconds", "paper_seconds"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise ValueError(f"{name} must be a finite number > 0 (s), got {v!r}")
        if any(not math.isfinite(a) or a < 0 for a in self.friction_levels) or not self.friction_levels:
            raise ValueError(f"friction_levels must be finite amplitudes >= 0 (N*m), got {self.friction_levels}")
        if (not self.step_amplitudes or any(not isinstance(a, (int, float)) or not math.isfinite(a) or a == 0
                                            for a in self.step_amplitudes)):
            raise ValueError(f"step_amplitudes must be finite non-zero numbers (output unit), got "
                             f"{self.step_amplitudes}")
        if any(not math.isfinite(m) or not 0 <= m < 1 for m in self.mismatch_levels) or not self.mismatch_levels:
            raise ValueError(f"mismatch_levels must be in [0, 1), got {self.mismatch_levels}")
        if self.plant is not None:
            try:
                object.__setattr__(self, "plant", as_rig(self.plant))
            except ValueError as exc:
                msg = str(exc)
                raise ValueError(msg if msg.startswith("plant") else f"plant: {msg}") from None
        object.__setattr__(self, "law_settings", law_table_of(self.law_settings))
        if self.episode_seconds <= SWEEP_WINDOW[1] and "robustness" in self.suites:
            raise ValueError(f"episode_seconds must be > {SWEEP_WINDOW[1]} s for the robustness sweeps, got "
                             f"{self.episode_seconds}")


@dataclass(frozen=True)
class Episode:
    """One pinned episode: its physical fields (:data:`ehss_gym.core.settings.PHYSICAL_FIELDS`) and labels.

    Attributes:
        suite: "paper", "heldout", "robustness", "step" or "unmodelled".
        task: "velocity" or "position".
        episode_id: unique within the suite and task (e.g. "heldout-3", "friction=1.8#0").
        physical: the scenario's physical fields (reference, friction, plant, model, noise, seed, t_end, ...).
        sweep: robustness episodes: "friction" or "mismatch"; "" otherwise.
        level: robustness episodes: the sweep level (friction amplitude [N*m] or relative mismatch [-]); step
            episodes: the step's amplitude [output unit].
        scenario_seed: the held-out scenario seed (-1 for the paper run).
    """

    suite: str
    task: str
    episode_id: str
    physical: dict = field(repr=False, hash=False, compare=False)
    sweep: str = ""
    level: float = math.nan
    scenario_seed: int = -1

    @property
    def t_end(self) -> float:
        """Duration of the episode [s]."""
        return float(self.physical["t_end"])


def _physical(sc) -> dict:
    """The physical fields of a Scenario (what an episode pins; the controller settings come from the env)."""
    return {f: getattr(sc, f) for f in PHYSICAL_FIELDS}


def _robustness_episodes(cfg: EvalConfig, task: str, tmpl) -> list[Episode]:
    """The friction sweep (plant = model) and the mismatch sweep of one task, noise removed."""
    out: list[Episode] = []
    nominal, model = tmpl.plant, tmpl.model or tmpl.plant  # the rig's plant and the controller's model of it
    base = heldout_scenarios(cfg.sweep_episodes, tmpl, cfg.episode_seconds, start=ROBUST_SEED_START)
    t0, t1 = SWEEP_WINDOW
    seed0 = HELDOUT_SEED_BASE + ROBUST_SEED_START
    for amp in cfg.friction_levels:
        for i, sc in enumerate(base):
            sc2 = sc.replace(friction=((float(amp), t0, t1),), plant=nominal, model=model, noise_std=NO_NOISE)
            out.append(Episode("robustness", task, f"friction={amp:g}#{i}", _physical(sc2), "friction", float(amp),
                               seed0 + i))
    for lvl in cfg.mismatch_levels:
        for i, sc in enumerate(base):
            signs = np.random.default_rng(ROBUST_SEED_START + i).choice([-1.0, 1.0], len(MISMATCH_PARAMS))
            plant = nominal.scaled(**{p: 1.0 + float(lvl) * s for p, s in zip(MISMATCH_PARAMS, signs)})
            sc2 = sc.replace(friction=((SWEEP_MISMATCH_FRICTION, t0, t1),), plant=plant, model=model,
                             noise_std=NO_NOISE)
            out.append(Episode("robustness", task, f"mismatch={lvl:g}#{i}", _physical(sc2), "mismatch", float(lvl),
                               seed0 + i))
    return out


def _step_episodes(cfg: EvalConfig, task: str, tmpl) -> list[Episode]:
    """The step suite of one task: one episode per amplitude, from rest."""
    out = []
    for a in cfg.step_amplitudes:
        sc = tmpl.replace(reference=step(float(a), STEP_TIME), friction=(), noise_std=NO_NOISE, seed=0,
                          t_end=STEP_SECONDS[task])  # the rig's plant and model, as the template has them
        out.append(Episode("step", task, f"step={a:+g}", _physical(sc), level=float(a)))
    return out


def step_of(ep: Episode) -> tuple[float, float]:
    """(step time [s], amplitude [output unit]) of a step-suite episode."""
    return STEP_TIME, float(ep.level)


def build_episodes(cfg: EvalConfig) -> list[Episode]:
    """Every episode of the configured suites and tasks, in a fixed order (task, then suite).

    Args:
        cfg: the evaluation's sizes.
    """
    out: list[Episode] = []
    for task in cfg.tasks:
        tmpl = EnvConfig.from_kwargs({"task": task, **cfg.env_kwargs()}).template()
        if "paper" in cfg.suites:
            out.append(Episode("paper", task, "paper", _physical(paper_scenario(tmpl, cfg.paper_seconds))))
        if "heldout" in cfg.suites:
            for i, sc in enumerate(heldout_scenarios(cfg.heldout_episodes, tmpl, cfg.episode_seconds)):
                out.append(Episode("heldout", task, f"heldout-{i}", _physical(sc), scenario_seed=HELDOUT_SEED_BASE + i))
        if "robustness" in cfg.suites:
            out += _robustness_episodes(cfg, task, tmpl)
        if "step" in cfg.suites:
            out += _step_episodes(cfg, task, tmpl)
        if "unmodelled" in cfg.suites:
            # the valve's threshold and hysteresis are percent of the rig's rated current (the template's)
            scs = heldout_scenarios(cfg.heldout_episodes, tmpl, cfg.episode_seconds, UNMODELLED_DISTRIBUTION,
                                    start=UNMODELLED_SEED_START)
            out += [Episode("unmodelled", task, f"unmodelled-{i}", _physical(sc),
                            scenario_seed=HELDOUT_SEED_BASE + UNMODELLED_SEED_START + i) for i, sc in enumerate(scs)]
    return out


__all__ = ["TASKS", "SUITES", "SUITE_ENV", "STEP_TIME", "STEP_AMPLITUDES", "STEP_SECONDS", "step_of", "UNITS",
           "ROBUST_SEED_START", "UNMODELLED_SEED_START", "SWEEP_WINDOW", "SWEEP_MISMATCH_FRICTION", "MISMATCH_PARAMS",
           "EvalConfig", "Episode", "build_episodes"]
