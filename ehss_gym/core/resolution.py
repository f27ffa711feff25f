"""What a real rig resolves and what its servo valve responds to: the physical floors of the ruler and of the env's
physical reward, each with its source.

- **Errors**: the smallest error the task's sensor resolves. Position: one count of the finest encoder the suites
  model, 2^20 counts per revolution (the unmodelled suite's range, :data:`ehss_gym.core.unmodelled.DATASHEET_RANGES`),
  2 pi / 2^20 = 5.99e-6 rad. Velocity: the finest velocity signal's step the suites model, 1e-4 rad/s (a 16-bit
  converter over +-3 rad/s).
- **Current**: the servo valve's threshold, 0.5 % of its rated current (Moog's datasheet bound, module
  :mod:`ehss_gym.core.unmodelled`), the smallest current step that moves the spool: 0.05 mA for Table I's 10 mA valve.
- **Control TV**: that threshold switched both ways once per period of the valve's bandwidth 1/(2 pi tau) (its
  first-order lag), the largest TV rate that can lie wholly below the threshold within the valve's band: for Table I's
  valve (tau = 10 ms: 15.9 Hz) 2 x 0.05 mA x 15.9 Hz = 1.59 mA/s.

The valve's floors follow the rig's valve (:func:`valve_floors` of its rated current and time constant); the module's
constants are Table I's, the floors of every result made without a plant.

Plain data (no numba).
"""

from __future__ import annotations

import math

from .params import PlantParams
from .unmodelled import DATASHEET_RANGES, DATASHEET_THRESHOLD, RATED_CURRENT

ENCODER_BITS = DATASHEET_RANGES.encoder_bits[1]  # the finest encoder the suites model: 2^20 counts per revolution
POSITION_RESOLUTION = 2.0 * math.pi / 2**ENCODER_BITS  # [rad] one count of it
VELOCITY_RESOLUTION = DATASHEET_RANGES.velocity_step[0]  # [rad/s] the finest velocity signal's step
ERROR_RESOLUTION = {"velocity": VELOCITY_RESOLUTION, "position": POSITION_RESOLUTION}  # task -> [output unit]


def valve_floors(rated_current: float, tau: float) -> tuple[float, float]:
    """(control TV floor [mA/s], RMS current floor [mA]) of a servo valve of rated current ``rated_current`` [mA] and
    time constant ``tau`` [s]: its threshold bound, 0.5 % of the rated current, and that threshold switched both ways
    once per period of its bandwidth 1/(2 pi tau)."""
    threshold = DATASHEET_THRESHOLD / 100.0 * rated_current
    return 2.0 * threshold / (2.0 * math.pi * tau), threshold


def floor_sources(rated_current: float, tau: float) -> dict:
    """Where each physical floor comes from (task -> text, "tv", "current"), for a valve of rated current
    ``rated_current`` [mA] and time constant ``tau`` [s]."""
    tv, threshold = valve_floors(rated_current, tau)
    band = 1.0 / (2.0 * math.pi * tau)
    return {
        "velocity": (f"the finest velocity signal the suites model, a step of {VELOCITY_RESOLUTION:g} rad/s (a 16-bit "
                     "converter over +-3 rad/s; ehss_gym.core.unmodelled.DATASHEET_RANGES)"),
        "position": (f"one count of a 2^{ENCODER_BITS}-count-per-revolution encoder, 2 pi / 2^{ENCODER_BITS} rad, the "
                     "finest the suites model (ehss_gym.core.unmodelled.DATASHEET_RANGES)"),
        "tv": (f"the valve's threshold ({DATASHEET_THRESHOLD:g} % of its {rated_current:g} mA rated current, Moog's "
               f"datasheet bound) switched both ways once per period of its bandwidth 1/(2 pi tau) = {band:.3g} Hz "
               f"(tau = {tau:g} s): 2 x {threshold:g} mA x {band:.3g} Hz"),
        "current": (f"the valve's threshold, {DATASHEET_THRESHOLD:g} % of its {rated_current:g} mA rated current "
                    "(Moog's datasheet bound): the smallest current step that moves the spool"),
    }


# Table I's valve (its 10 mA rated current and 10 ms time constant): the floors of every result made without a plant
VALVE_BANDWIDTH = 1.0 / (2.0 * math.pi * PlantParams().tau)  # [Hz] the valve lag's corner frequency
TV_FLOOR, VALVE_THRESHOLD = valve_floors(RATED_CURRENT, PlantParams().tau)  # [mA/s], [mA]
CURRENT_FLOOR = VALVE_THRESHOLD  # [mA]
FLOOR_SOURCES = floor_sources(RATED_CURRENT, PlantParams().tau)

__all__ = ["ENCODER_BITS", "POSITION_RESOLUTION", "VELOCITY_RESOLUTION", "ERROR_RESOLUTION", "VALVE_THRESHOLD",
           "VALVE_BANDWIDTH", "TV_FLOOR", "CURRENT_FLOOR", "FLOOR_SOURCES", "valve_floors", "floor_sources"]
