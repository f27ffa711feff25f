"""Metrics on synthetic signals with known answers."""

import math

import numpy as np
import pytest

from ehss_gym.core.metrics import RECOVERY_SHARE, recovery_times


def test_recovery_is_the_settling_time_into_the_larger_band():
    """A 0.05 error spike at the friction edge decaying with a 10 ms time constant onto a 1e-3 offset, from a
    1e-6 pre-friction error: the band is 10 % of the peak (5e-3), entered at 10 ms * ln(0.05 / 4e-3)."""
    t = np.arange(0.0, 3.0, 1e-4)
    e = np.full_like(t, 1e-6)
    on, off = 1.0, 2.0
    d = t - on
    e[(t >= on) & (t < off)] = 0.05 * np.exp(-d[(t >= on) & (t < off)] / 0.01) + 1e-3
    d = t - off
    e[t >= off] = -0.02 * np.exp(-d[t >= off] / 0.005)
    r_on, r_off = recovery_times(t, e, ((1.8, on, off),))
    assert RECOVERY_SHARE == 0.1
    assert r_on == pytest.approx(0.01 * math.log(0.05 / (0.1 * 0.051 - 1e-3)), abs=2e-4)
    assert r_off == pytest.approx(0.005 * math.log(0.02 / 0.002), abs=2e-4)


def test_recovery_is_never_when_the_error_grows():
    t = np.arange(0.0, 2.0, 1e-3)
    e = np.where(t >= 1.0, 0.01 * (t - 1.0), 1e-4)
    assert math.isinf(recovery_times(t, e, ((1.0, 1.0, 5.0),))[0])


def test_pre_friction_band_still_counts_for_a_chattering_loop():
    """A relay's 1e-3 chatter before the edge sets the band when it exceeds 10 % of the edge peak."""
    t = np.arange(0.0, 2.0, 1e-4)
    e = 1e-3 * np.sign(np.sin(2 * np.pi * 500 * t))
    sel = t >= 1.0
    e[sel] += 0.005 * np.exp(-(t[sel] - 1.0) / 0.01)
    r_on, _ = recovery_times(t, e, ((1.8, 1.0, 1.9),))
    # band 2e-3 (> 10 % of the ~6e-3 peak): |e| <= 2e-3 once 5e-3 exp(-x/0.01) + 1e-3 <= 2e-3
    assert r_on == pytest.approx(0.01 * math.log(5.0), abs=1.1e-3)  # to within the 1 ms half-period of the chatter
