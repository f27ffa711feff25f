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


def test_the_probe_is_a_square_wave_of_its_period_on_every_entry_and_zero_without_it():
    obs = np.zeros((3, 5))
    rec = di.Recorder(2, probe=0.5, period=4)
    acts = [rec.predict(obs)[0] for _ in range(8)]
    assert all(a.shape == (3, 2) and np.all(a == a[0, 0]) for a in acts)
    assert [float(a[0, 0]) for a in acts] == [0.5, 0.5, -0.5, -0.5] * 2
    assert len(rec.seen) == 8
    base = di.Recorder(2)
    assert not base.predict(obs)[0].any()
    short = di.Recorder(1, probe=1.0, period=2, steps=3)  # the first 3 agent steps only
    assert [float(short.predict(obs)[0][0, 0]) for _ in range(5)] == [1.0, -1.0, 1.0, 0.0, 0.0]


def test_the_probe_cost_is_one_on_the_base_laws_own_runs_and_counts_the_current_it_adds():
    from ehss_gym.envs.rollouts import rollout
    from ehss_gym.evaluation.suites import EvalConfig, build_episodes

    (ep,) = build_episodes(EvalConfig(suites=("unmodelled",), tasks=("position",), heldout_episodes=1))
    kw = {"task": "position", "n": 2, "mode": "residual"}
    (res,) = rollout(di.Recorder(1), kw, [ep.physical])
    m, runs = res.metrics, [ep.physical]
    g, cls = di.probe_cost([m], [m], runs, "position")
    assert g == 1.0 and cls and all(v == 1.0 for v in cls.values())
    more = {**m, "tv_u_rate": 16.0 * m["tv_u_rate"]}  # the probe's current changes: 16x the rate
    g2, cls2 = di.probe_cost([more], [m], runs, "position")
    current = "chatter" if "chatter" in cls2 else "effort"
    assert cls2[current] > 1.5 and g2 > 1.1 and cls2["tracking"] == 1.0
