"""The servo valve and sensors the law's model leaves out: one typed, validated record and the ranges episodes draw.

The law is designed on Eq. (1) (:mod:`ehss_gym.core.physics`), which models the servo valve as a first-order lag
x4' = (K u - x4)/tau driven by the commanded current and the controller as measuring the plant's state exactly and at
once. Real hardware differs in four ways a model-based law cannot cancel (docs/MODEL.md, "Unmodelled valve and
sensors"):

- **valve threshold (dead band)**: the torque motor does not move the spool for a current below the threshold;
- **valve hysteresis**: on the way up and on the way down the same current gives different spool positions;
- **sensor delay**: the controller receives the measurement some samples late (conversion, a field bus);
- **encoder quantisation**: the measured position is on a grid of counts, the measured velocity on a grid of its own.

Sizes. A servo valve's datasheet states threshold and hysteresis in percent of its *rated current* (the current, of
either polarity, that gives rated flow: 10 mA here, the loop's current limit). Moog's definitions (Moog Inc.,
"Electrohydraulic Valves... A Technical Look", sections "General Terminology" and "Performance Characteristics";
https://studylib.net/doc/18664527/electrohydraulic-valves): *threshold* is the increment of input current needed to
produce a change in valve output, *hysteresis* the difference between the currents that give the same output on a
slowly cycled input, both in percent of rated current. The two-stage flow-control servo valves of that catalogue
(e.g. the G761 and G77x series) state hysteresis < 3 % and threshold < 0.5 % of rated current; those bounds set
:data:`DATASHEET_RANGES`.

Everything here is plain data (no numba): :mod:`ehss_gym.core.settings` puts the record into the controller row and
:mod:`ehss_gym.core.unmodelled_kernels` applies it in the loop.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .layout import MAX_DELAY
from .validate import check_finite, check_int

RATED_CURRENT = 10.0  # [mA] the servo valve's rated current (Table I's valve at the env's 10 mA current limit)
THRESHOLD_MAX = 10.0  # [% of rated current] largest threshold accepted (20x the datasheet bound)
HYSTERESIS_MAX = 30.0  # [% of rated current] largest hysteresis accepted (10x the datasheet bound)
VELOCITY_STEP_MAX = 10.0  # [rad/s] largest velocity quantisation step accepted
ENCODER_COUNTS_RANGE = (4, 2**40)  # [counts per revolution] accepted encoder resolutions (0 = not quantised)
# Datasheet bounds (Moog flow-control servo valves, module docstring)
DATASHEET_THRESHOLD = 0.5  # [% of rated current]
DATASHEET_HYSTERESIS = 3.0  # [% of rated current]


@dataclass(frozen=True)
class Unmodelled:
    """The valve and sensor effects of one episode; every field 0 (the default) = the effect is off.

    Attributes:
        threshold: servo-valve threshold (dead band) [% of ``rated_current``], in [0, THRESHOLD_MAX = 10]. The valve
            is driven by u_eff = u - sign(u) th for |u| > th = threshold * rated_current / 100 and by 0 below: the
            continuous dead zone (no jump of the valve's input where |u| crosses th, which a held current would turn
            into a step of the spool at every crossing).
        hysteresis: servo-valve hysteresis [% of ``rated_current``], in [0, HYSTERESIS_MAX = 30]: the total width h
            of a play (backlash) operator on the current after the dead band; its output, which drives the valve's
            first-order lag, moves only once the input has moved h/2 past it (a loop of width h on a slow cycle).
        delay: sensor delay [control samples], an integer in [0, MAX_DELAY = 8]: the controller sees at sample k the
            measurement (all four measured states, with their noise and quantisation) of sample k - delay; before
            the first sample the plant was at rest at its initial state.
        encoder_counts: position encoder resolution [counts per revolution], 0 (off) or an integer in
            [4, 2^40]: the measured position x1 is rounded to the nearest multiple of 2 pi / encoder_counts [rad]
            (error <= half a count; an interpolating decoder's reading).
        velocity_step: quantisation step of the measured velocity x2 [rad/s], in [0, VELOCITY_STEP_MAX = 10]: a
            velocity signal's resolution, rounded to the nearest multiple. A velocity differenced from an encoder
            of N counts over one control period h has the step 2 pi / (N h) (a 2^23-count encoder at h = 50 us:
            0.015 rad/s); an explicit step keeps the two quantisations independent of the control period.
        rated_current: the valve's rated current [mA] (> 0) that ``threshold`` and ``hysteresis`` are percent of.
    """

    threshold: float = 0.0
    hysteresis: float = 0.0
    delay: int = 0
    encoder_counts: int = 0
    velocity_step: float = 0.0
    rated_current: float = RATED_CURRENT

    def __post_init__(self):
        """Raises ValueError naming the first field out of range."""
        object.__setattr__(self, "threshold", check_finite("unmodelled.threshold", self.threshold, low=0.0,
                                                           high=THRESHOLD_MAX))
        object.__setattr__(self, "hysteresis", check_finite("unmodelled.hysteresis", self.hysteresis, low=0.0,
                                                            high=HYSTERESIS_MAX))
        object.__setattr__(self, "delay", check_int("unmodelled.delay (control samples)", self.delay, 0, MAX_DELAY))
        lo, hi = ENCODER_COUNTS_RANGE
        try:
            counts = check_int("unmodelled.encoder_counts", self.encoder_counts, 0, hi)
        except ValueError:
            counts = -1
        if counts < 0 or 0 < counts < lo:
            raise ValueError(f"unmodelled.encoder_counts must be 0 (off) or an integer in [{lo}, {hi}] (counts per "
                             f"revolution), got {self.encoder_counts!r}")
        object.__setattr__(self, "encoder_counts", counts)
        object.__setattr__(self, "velocity_step", check_finite("unmodelled.velocity_step", self.velocity_step,
                                                               low=0.0, high=VELOCITY_STEP_MAX))
        rated = check_finite("unmodelled.rated_current", self.rated_current, low=0.0, low_open=True)
        object.__setattr__(self, "rated_current", rated)

    @property
    def threshold_current(self) -> float:
        """The threshold th [mA]."""
        return self.threshold * self.rated_current / 100.0

    @property
    def hysteresis_current(self) -> float:
        """The hysteresis loop's total width h [mA]."""
        return self.hysteresis * self.rated_current / 100.0

    @property
    def position_step(self) -> float:
        """The encoder's count 2 pi / encoder_counts [rad]; 0 = not quantised."""
        return 2.0 * math.pi / self.encoder_counts if self.encoder_counts else 0.0

    @property
    def off(self) -> bool:
        """Every effect is off (the loop is the model's)."""
        return (self.threshold == 0.0 and self.hysteresis == 0.0 and self.delay == 0 and self.encoder_counts == 0
                and self.velocity_step == 0.0)


NONE = Unmodelled()


@dataclass(frozen=True)
class UnmodelledRanges:
    """The ranges an episode draws its :class:`Unmodelled` effects from (:meth:`draw`).

    Attributes:
        threshold: uniform range of the threshold [% of rated current].
        hysteresis: uniform range of the hysteresis [% of rated current].
        delay: inclusive range of the sensor delay [control samples], integers equally likely.
        encoder_bits: inclusive range of b, the encoder then has 2^b counts per revolution, integers equally likely.
        velocity_step: log-uniform range of the velocity quantisation step [rad/s].
        share: the share of episodes that have the effects, in (0, 1]; the others have none. Drawn after the effects,
            so an episode that has them has the same effects at any share (and at 1 nothing more is drawn).
    """

    threshold: tuple[float, float] = (0.5 * DATASHEET_THRESHOLD, DATASHEET_THRESHOLD)
    hysteresis: tuple[float, float] = (0.5 * DATASHEET_HYSTERESIS, DATASHEET_HYSTERESIS)
    delay: tuple[int, int] = (1, 2)
    encoder_bits: tuple[int, int] = (16, 20)
    velocity_step: tuple[float, float] = (1e-4, 1e-3)
    share: float = 1.0

    def __post_init__(self):
        object.__setattr__(self, "share", check_finite("unmodelled share", self.share, low=0.0, high=1.0,
                                                       low_open=True))

    def draw(self, rng: np.random.Generator) -> Unmodelled:
        """One episode's effects, drawn with ``rng`` (:data:`NONE` for an episode outside the share)."""
        bits = int(rng.integers(self.encoder_bits[0], self.encoder_bits[1] + 1))
        lo, hi = self.velocity_step
        effects = Unmodelled(threshold=float(rng.uniform(*self.threshold)),
                          hysteresis=float(rng.uniform(*self.hysteresis)),
                          delay=int(rng.integers(self.delay[0], self.delay[1] + 1)),
                          encoder_counts=2**bits,
                          velocity_step=float(math.exp(rng.uniform(math.log(lo), math.log(hi)))))
        return effects if self.share == 1.0 or rng.uniform() < self.share else NONE


# The sizes the unmodelled suite and the randomised training option draw: a valve in the upper half of its datasheet's
# bounds (threshold 0.25-0.5 %, hysteresis 1.5-3 % of rated current: it meets its datasheet, not by much), a
# measurement one or two samples late (read at the sample and delivered to the next; one more for a bus cycle), a
# 16- to 20-bit position encoder (9.6e-5 to 6.0e-6 rad per count) and a velocity signal with a step of 1e-4 to
# 1e-3 rad/s (a 16-bit converter over a +-3 to +-30 rad/s span; a step of 1e-2 rad/s, what a 2^23-count encoder
# differenced over 50 us gives, makes the paper's velocity loop lose track: its SVF differentiates the steps twice).
DATASHEET_RANGES = UnmodelledRanges()
UNMODELLED_STREAM = 0x554E4D  # second key of the generator that draws an episode's effects from its scenario seed


def draw_unmodelled(scenario_seed: int, ranges: UnmodelledRanges = DATASHEET_RANGES) -> Unmodelled:
    """The effects of the episode with scenario seed ``scenario_seed``: a pure function of it, from a generator of
    its own (keyed by the seed and :data:`UNMODELLED_STREAM`), so the rest of the episode's draw is unchanged."""
    return ranges.draw(np.random.default_rng([int(scenario_seed), UNMODELLED_STREAM]))


__all__ = ["Unmodelled", "UnmodelledRanges", "NONE", "DATASHEET_RANGES", "draw_unmodelled", "RATED_CURRENT",
           "THRESHOLD_MAX", "HYSTERESIS_MAX", "VELOCITY_STEP_MAX", "ENCODER_COUNTS_RANGE", "DATASHEET_THRESHOLD",
           "DATASHEET_HYSTERESIS", "UNMODELLED_STREAM"]
