"""Episode scenarios for the Gymnasium env: the paper's run and a randomised training distribution.

A scenario is a core :class:`~ehss_gym.core.settings.Scenario`. The env supplies the controller settings (task, n,
f_r, sigma, smoothing, current limit, control period, substeps, estimator); this module supplies the
*physical* episode: the reference, the friction events, the true plant (model mismatch), the sensor
noise, the noise seed and the duration (:data:`PHYSICAL_FIELDS`).

- ``"paper"``: the paper's 20 s run, a 1 (rad/s or rad) 2 rad/s sine with 1.8 N*m Coulomb friction
  from 8 s to 10 s, no mismatch, no noise (:func:`paper_scenario`).
- ``"random"``: :func:`sample_scenario` draws one episode from :class:`Distribution` as a pure function
  of an integer *scenario seed*. The env draws training scenario seeds in ``[0, TRAIN_SEED_LIMIT)``;
  :func:`heldout_scenarios` uses seeds ``>= TRAIN_SEED_LIMIT``, so held-out scenarios can never be
  drawn in training, whatever seeds training used.

The distribution (defaults of :class:`Distribution`, velocity task; output unit rad/s, or rad for the
position task):

==================  ===========================================================================
reference family    sine, step, chirp, multi-sine, equally likely
amplitude           uniform 0.2 .. 1.5 (multi-sine: total, split over 2-4 components)
offset              uniform -0.5 .. 0.5
frequency           log-uniform 0.5 .. 20 rad/s velocity, 0.5 .. 5 rad/s position (chirp sweeps
                    from the low to a high draw over the episode; step at 5-50 % of the episode)
friction events     0, 1, 2, 3 events with probabilities 0.1, 0.4, 0.3, 0.2; amplitude uniform
                    0 .. 3.6 N*m (up to 2x the paper's 1.8); start uniform over the episode;
                    duration uniform 0.05 .. 1 s (may run past the end); events may overlap (add)
model mismatch      true plant beta, J, B, c_sm, P_s each scaled by uniform 0.8 .. 1.2 around the
                    template's plant (Table I, or a plant file's: the env's ``plant``); the controller
                    keeps the template's model (the model the law was designed with: the plant's
                    nominal parameters unless a plant file gives its own)
sensor noise        with probability 0.5, Gaussian noise with std uniform 0 .. 1 times
                    (1e-5 rad, 1e-4 rad/s, 2e3 Pa, 1e-10 m^2) on the measured x1..x4
duration            ``episode_seconds`` (default 2 s)
unmodelled effects  none; with ``Distribution.unmodelled`` (:data:`UNMODELLED_DISTRIBUTION`, the env's
                    ``unmodelled_effects=True``): valve threshold 0.25-0.5 % and hysteresis 1.5-3 %
                    of rated current, sensor delay 1-2 samples, a 16-20 bit position encoder, a
                    velocity step 1e-4-1e-3 rad/s (:data:`ehss_gym.core.unmodelled.DATASHEET_RANGES`)
==================  ===========================================================================
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace

import numpy as np

from .params import PlantParams
from .settings import PAPER_FRICTION, PHYSICAL_FIELDS, Scenario
from .signals import FAMILIES, chirp, multisine, paper_reference, sine, step
from .unmodelled import DATASHEET_RANGES, NONE, UnmodelledRanges, draw_unmodelled

TRAIN_SEED_LIMIT = 2**62  # training scenario seeds are < this; held-out seeds are >= this
HELDOUT_SEED_BASE = TRAIN_SEED_LIMIT
PAPER_T_END = 20.0  # [s]
MISMATCH_PARAMS = ("beta", "J", "B", "c_sm", "P_s")


@dataclass(frozen=True)
class Distribution:
    """Ranges of the randomised training distribution (see the module docstring).

    Attributes:
        episode_seconds: episode duration [s].
        amplitude: reference amplitude range [output unit].
        offset: reference offset range [output unit].
        omega_velocity: reference angular-frequency range, velocity task [rad/s] (log-uniform).
        omega_position: the same for the position task [rad/s].
        friction_count_probs: probabilities of 0, 1, 2, ... friction events.
        friction_amplitude: event amplitude range [N*m].
        friction_duration: event duration range [s].
        mismatch: relative half-width of the plant-parameter scaling (0.2 = +-20 %).
        noise_probability: probability that an episode has sensor noise.
        noise_std_max: largest noise std of (x1 [rad], x2 [rad/s], x3 [Pa], x4 [m^2]).
        unmodelled: the ranges of the valve and sensor effects the law's model leaves out, drawn from a generator
            of their own (:func:`ehss_gym.core.unmodelled.draw_unmodelled`, so the other draws are unchanged); None
            = none (the default).
    """

    episode_seconds: float = 2.0
    amplitude: tuple[float, float] = (0.2, 1.5)
    offset: tuple[float, float] = (-0.5, 0.5)
    omega_velocity: tuple[float, float] = (0.5, 20.0)
    omega_position: tuple[float, float] = (0.5, 5.0)
    friction_count_probs: tuple[float, ...] = (0.1, 0.4, 0.3, 0.2)
    friction_amplitude: tuple[float, float] = (0.0, 3.6)
    friction_duration: tuple[float, float] = (0.05, 1.0)
    mismatch: float = 0.2
    noise_probability: float = 0.5
    noise_std_max: tuple[float, float, float, float] = (1e-5, 1e-4, 2e3, 1e-10)
    unmodelled: UnmodelledRanges | None = None


DEFAULT_DISTRIBUTION = Distribution()
UNMODELLED_DISTRIBUTION = Distribution(unmodelled=DATASHEET_RANGES)  # the env's unmodelled_effects=True


def unmodelled_distribution(share: float = 1.0) -> Distribution:
    """The distribution with the unmodelled effects on a ``share`` of the episodes (1: :data:`UNMODELLED_DISTRIBUTION`;
    the env's ``unmodelled_effects=True`` with ``unmodelled_share``)."""
    if share == 1.0:
        return UNMODELLED_DISTRIBUTION
    return Distribution(unmodelled=replace(DATASHEET_RANGES, share=share))


def paper_scenario(template: Scenario, t_end: float | None = None) -> Scenario:
    """The paper's run on the controller settings and the plant of ``template``.

    Args:
        template: a Scenario carrying the controller settings (task, n, sigma, ...) and the rig: its ``plant`` and
            the controller's ``model`` (None: the plant's), kept as they are (Table I's unless the template was made
            for another plant, ``EnvConfig(plant=...)``).
        t_end: duration [s]; None = the paper's 20 s.
    """
    return template.replace(reference=paper_reference(), friction=PAPER_FRICTION, noise_std=(0.0, 0.0, 0.0, 0.0),
                            seed=0, t_end=PAPER_T_END if t_end is None else t_end, unmodelled=NONE)


def _loguniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def sample_scenario(scenario_seed: int, template: Scenario, episode_seconds: float | None = None,
                    dist: Distribution = DEFAULT_DISTRIBUTION) -> Scenario:
    """Draw one episode of the training distribution; a pure function of ``scenario_seed``.

    Args:
        scenario_seed: integer >= 0 (training uses [0, TRAIN_SEED_LIMIT)).
        template: a Scenario carrying the controller settings and the rig: the plant's mismatch is drawn around
            ``template.plant``, the controller keeps ``template.model`` (the plant's parameters if None), and the
            valve's threshold and hysteresis drawn (``dist.unmodelled``) are percent of ``template.rated_current``.
        episode_seconds: duration [s]; None = ``dist.episode_seconds``.
        dist: the distribution.
    """
    if isinstance(scenario_seed, bool) or not isinstance(scenario_seed, (int, np.integer)) or scenario_seed < 0:
        raise ValueError(f"scenario_seed must be an integer >= 0, got {scenario_seed!r}")
    rng = np.random.default_rng(int(scenario_seed))
    T = float(dist.episode_seconds if episode_seconds is None else episode_seconds)
    lo, hi = dist.omega_velocity if template.task == "velocity" else dist.omega_position
    family = FAMILIES[int(rng.integers(len(FAMILIES)))]
    amp = float(rng.uniform(*dist.amplitude))
    off = float(rng.uniform(*dist.offset))
    if family == "sine":
        ref = sine(amp, _loguniform(rng, lo, hi), float(rng.uniform(0.0, 2 * math.pi)), off)
    elif family == "step":
        ref = step(amp * float(rng.choice([-1.0, 1.0])), float(rng.uniform(0.05, 0.5)) * T, off)
    elif family == "chirp":
        w0 = _loguniform(rng, lo, math.sqrt(lo * hi))
        w1 = _loguniform(rng, math.sqrt(lo * hi), hi)
        ref = chirp(amp, w0, w1, 0.0, T, float(rng.uniform(0.0, 2 * math.pi)))
    else:
        k = int(rng.integers(2, 5))
        share = rng.dirichlet(np.ones(k))
        ref = multisine((amp * share).tolist(), [_loguniform(rng, lo, hi) for _ in range(k)],
                        rng.uniform(0.0, 2 * math.pi, k).tolist(), off)
    p = np.asarray(dist.friction_count_probs, dtype=float)
    count = int(rng.choice(len(p), p=p / p.sum()))
    events = []
    for _ in range(count):
        t0 = float(rng.uniform(0.0, T))
        fa = float(rng.uniform(*dist.friction_amplitude))
        events.append((fa, t0, t0 + float(rng.uniform(*dist.friction_duration))))
    events.sort(key=lambda ev: ev[1])
    nominal = template.plant
    factors = {name: float(rng.uniform(1.0 - dist.mismatch, 1.0 + dist.mismatch)) for name in MISMATCH_PARAMS}
    plant = nominal.scaled(**factors)
    if rng.uniform() < dist.noise_probability:
        noise = tuple(float(rng.uniform(0.0, 1.0)) * s for s in dist.noise_std_max)
    else:
        noise = (0.0, 0.0, 0.0, 0.0)
    noise_seed = int(rng.integers(0, 2**52))
    unmodelled = NONE if dist.unmodelled is None else draw_unmodelled(int(scenario_seed), dist.unmodelled)
    if not unmodelled.off and unmodelled.rated_current != template.rated_current:  # the rig's valve's sizes
        unmodelled = replace(unmodelled, rated_current=template.rated_current)
    model = nominal if template.model is None else template.model
    return template.replace(reference=ref, friction=tuple(events), plant=plant, model=model, noise_std=noise,
                            seed=noise_seed, t_end=T, unmodelled=unmodelled)


def heldout_scenarios(count: int, template: Scenario, episode_seconds: float | None = None,
                      dist: Distribution = DEFAULT_DISTRIBUTION, start: int = 0) -> list[Scenario]:
    """Scenarios from seeds ``HELDOUT_SEED_BASE + start + i``, disjoint from every training seed.

    Args:
        count: number of scenarios (>= 1).
        template: a Scenario carrying the controller settings (``env.unwrapped.scenario_template``).
        episode_seconds: duration [s]; None = ``dist.episode_seconds``.
        dist: the distribution.
        start: offset of the first held-out seed (>= 0), to draw further disjoint batches.
    """
    if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or count < 1:
        raise ValueError(f"count must be an integer >= 1, got {count!r}")
    if isinstance(start, bool) or not isinstance(start, (int, np.integer)) or start < 0:
        raise ValueError(f"start must be an integer >= 0, got {start!r}")
    return [sample_scenario(HELDOUT_SEED_BASE + int(start) + i, template, episode_seconds, dist) for i in range(count)]


def _ratio(a: float, b: float) -> float:
    """a / b, with 0 / 0 = 1 (a parameter the rig has at 0: no damping, no leakage, stays 0)."""
    return a / b if b != 0.0 else (1.0 if a == 0.0 else math.inf)


def describe(sc: Scenario, nominal: PlantParams | None = None) -> dict:
    """What an episode drew, as plain Python values (for ``info``).

    Args:
        sc: the episode.
        nominal: the plant its mismatch was drawn around (default Table I): ``plant_scaling`` is the episode's plant
            over it, parameter by parameter.
    """
    nominal = PlantParams() if nominal is None else nominal
    return {
        "reference": sc.reference.description,
        "reference_family": sc.reference.family,
        "friction": [tuple(ev) for ev in sc.friction],
        "plant_scaling": {name: _ratio(getattr(sc.plant, name), getattr(nominal, name)) for name in MISMATCH_PARAMS},
        "model_mismatch": sc.model is not None and sc.model != sc.plant,
        "noise_std": tuple(sc.noise_std),
        "noise_seed": int(sc.seed),
        "t_end": sc.t_end,
        "unmodelled": asdict(sc.unmodelled),
    }


def controller_mismatch(sc: Scenario, template: Scenario) -> list[str]:
    """Names of the non-physical fields on which ``sc`` differs from ``template``."""
    phys = set(PHYSICAL_FIELDS)
    return [f.name for f in fields(Scenario) if f.name not in phys and getattr(sc, f.name) != getattr(template, f.name)]


__all__ = ["Distribution", "DEFAULT_DISTRIBUTION", "UNMODELLED_DISTRIBUTION", "unmodelled_distribution",
           "paper_scenario", "sample_scenario", "heldout_scenarios",
           "describe", "controller_mismatch", "TRAIN_SEED_LIMIT", "HELDOUT_SEED_BASE", "PHYSICAL_FIELDS"]
