"""The one module of validators: every bad value raises a ValueError naming the parameter and the accepted range.

The records (:class:`~ehss_gym.core.params.PlantParams`, :class:`~ehss_gym.core.settings.Scenario`,
:class:`~ehss_gym.envs.config.EnvConfig`, the agents' and the study's configs) and the CLI's argparse
types (:mod:`ehss_gym.cli.options`) all check through these functions, so a message reads the same wherever
the value came from.
"""

from __future__ import annotations

import math

import numpy as np


def check_finite(name: str, value, *, low=None, high=None, low_open=False, high_open=False):
    """Return ``float(value)`` or raise a ValueError naming ``name`` and its accepted range.

    Args:
        name: parameter name shown in the error.
        value: the value to check.
        low, high: bounds (None = unbounded).
        low_open, high_open: whether the bound itself is excluded.
    """
    rng = range_text(low, high, low_open, high_open)
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a finite number in {rng}, got {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{name} must be a finite number in {rng}, got {value!r}")
    if low is not None and (v < low or (low_open and v == low)):
        raise ValueError(f"{name} must be in {rng}, got {v:g}")
    if high is not None and (v > high or (high_open and v == high)):
        raise ValueError(f"{name} must be in {rng}, got {v:g}")
    return v


def range_text(low: float | None, high: float | None, low_open: bool = False, high_open: bool = False) -> str:
    """An interval as the errors write it, e.g. ``(0, 1000]`` or ``[0, inf)``."""
    lo = "-inf" if low is None else f"{low:g}"
    hi = "inf" if high is None else f"{high:g}"
    return f"{'(' if low is None or low_open else '['}{lo}, {hi}{')' if high is None or high_open else ']'}"


def check_number(name: str, value, *, unit: str, low=None, high=None, low_open=False, high_open=False) -> float:
    """A real number (an int or a float, NumPy's too; not a bool or a string) in the range, as a float.

    Unlike :func:`check_finite`, text that looks like a number (``"0.02"``) is refused: a record built from a file or a
    dict must not depend on how a parser typed its values.

    Raises:
        ValueError: naming ``name``, its unit and the accepted range.
    """
    rng = range_text(low, high, low_open, high_open)
    what = f"{name} [{unit}] must be a finite number in {rng}"
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{what}, got {value!r} (a {type(value).__name__})")
    v = float(value)
    if not math.isfinite(v) or (low is not None and (v < low or (low_open and v == low))) \
            or (high is not None and (v > high or (high_open and v == high))):
        raise ValueError(f"{what}, got {v:g}")
    return v


def check_positive(name: str, value) -> float:
    """A finite, strictly positive float, or a ValueError naming ``name``."""
    return check_finite(name, value, low=0.0, low_open=True)


def check_int(name: str, value, low: int | None = None, high: int | None = None) -> int:
    """An integer (a float with an integer value is accepted; a bool is not) in [low, high], or a ValueError."""
    rng = ("an integer" + (f" >= {low}" if low is not None and high is None else "")
           + (f" in [{low}, {high}]" if low is not None and high is not None else "")
           + (f" <= {high}" if high is not None and low is None else ""))
    if isinstance(value, bool) or not isinstance(value, (int, np.integer, float)) or not float(value).is_integer():
        raise ValueError(f"{name} must be {rng}, got {value!r}")
    if (low is not None and value < low) or (high is not None and value > high):
        raise ValueError(f"{name} must be {rng}, got {value!r}")
    return int(value)


def check_choice(name: str, value, valid):
    """``value`` if it is one of ``valid``, else a ValueError listing them."""
    if value not in valid:
        raise ValueError(f"{name} must be one of {list(valid)}, got {value!r}")
    return value


def check_bool(name: str, value) -> bool:
    """``value`` if it is a bool (numpy's too), else a ValueError."""
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def check_even_n(n, name: str = "n") -> int:
    """An even integer power factor >= 2, or a ValueError."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer, float)) or not float(n).is_integer() \
            or n < 2 or int(n) % 2:
        raise ValueError(f"{name} must be an even integer >= 2 (2, 4, 6, ...), got {n!r}")
    return int(n)
