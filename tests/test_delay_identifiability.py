"""The delay-identifiability tool's classifier (tools/delay_identifiability.py): it finds a class a feature carries,
finds none in noise; its rate slope recovers a known gain."""

import importlib.util
from pathlib import Path

import numpy as np

_spec = importlib.util.spec_from_file_location(
    "delay_identifiability", Path(__file__).resolve().parents[1] / "tools" / "delay_identifiability.py")
di = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(di)


def test_the_classifier_finds_a_carried_class_and_none_in_noise():
    rng = np.random.default_rng(0)
    n, d = 200, 20
    y = np.repeat([0.0, 1.0], n // 2)
    group = np.tile(np.arange(n // 2), 2)
    X = rng.normal(size=(n, d))
    assert di.cv_accuracy(X, y, group) < 0.65  # noise: chance
    X[:, 3] += 1.5 * (2 * y - 1)  # one feature carries the class
    assert di.cv_accuracy(X, y, group) > 0.85
    lo, hi = di.wilson(0.5, 400)
    assert lo < 0.5 < hi and abs((hi - lo) - 0.098) < 0.002


def test_the_rate_slope_is_the_gain_on_the_rate():
    t = np.linspace(0.0, 2.0, 2001)
    rate = np.cos(3.0 * t)
    x = np.column_stack([2.5e-4 * rate + 0.1, np.sin(3.0 * t)])
    f = di.features(x, rate).reshape(-1, 2)  # rows: mean, std, lags..., slope, corr
    slope, corr = f[-2], f[-1]
    assert abs(slope[0] - 2.5e-4) < 1e-12 and abs(corr[0] - 1.0) < 1e-9 and abs(corr[1]) < 0.05
