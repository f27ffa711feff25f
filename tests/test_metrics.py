"""Metrics on synthetic signals with known answers."""

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies

from ehss_gym.core import layout
from ehss_gym.core.metrics import RECOVERY_SHARE, recovery_times
from ehss_gym.core.signals import multisine, step
from ehss_gym.core.sim import Scenario, simulate, simulate_batch


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


# ---------------------------------------------------------------------------------------------------
# The metric classes: the compiled accumulators against a numpy recomputation from a full-rate log, with the
# windows built here from the scenario's friction list (not from the controller's window flag)

T_SU, T_GUARD = 0.2, 0.2  # [s] the start-up window and the guard after each friction event (core.layout)


def _windows(t, friction):
    """(start-up, disturbance, tracking) masks of the sample times ``t`` for friction events (a, t_on, t_off)."""
    su = t < T_SU
    ev = np.zeros(len(t), dtype=bool)
    for _, t_on, t_off in friction:
        ev |= (t >= t_on) & (t < t_off + T_GUARD)
    dst = ~su & ev
    return su, dst, ~su & ~ev


def _reference_metrics(traj):
    """The class metrics recomputed in numpy from a trajectory logged at every control period."""
    sc = traj.scenario
    h = sc.control_period
    t = traj.t
    y = traj.x[:, 1 if sc.task == "velocity" else 0]
    et = y - traj.y_ref  # the true error
    su, dst, trk = _windows(t, sc.friction)
    u = traj.u_applied
    return {"trk_rmse": np.sqrt(np.mean(et[trk] ** 2)), "trk_iae": np.sum(np.abs(et[trk])) * h,
            "dst_peak": np.max(np.abs(et[dst])), "dst_iae": np.sum(np.abs(et[dst])) * h,
            "su_rmse": np.sqrt(np.mean(et[su] ** 2)), "su_iae": np.sum(np.abs(et[su])) * h,
            "su_peak": np.max(np.abs(et[su])), "iae_r": np.sum(np.abs(y - traj.r)) * h,
            "tv_u_rate": np.sum(np.abs(np.diff(u))) / (len(u) * h), "rms_u": np.sqrt(np.mean(u ** 2)),
            "steps_startup": su.sum(), "steps_disturbance": dst.sum(), "steps_tracking": trk.sum(),
            "v_decrease": np.sum(traj.V[1:] < traj.V[:-1]) / max(len(t) - 1, 1)}


def _scenario(task, friction, noise, **kw):
    h = 5e-5
    base = dict(task=task, control_period=h, substeps=1, log_interval=h, current_limit=10.0, t_end=1.2,
                friction=friction, noise_std=noise, seed=7, bumpless=True, smoothing=100.0, layer_gain=3.0,
                sigma=1e5 if task == "velocity" else 1e6, fr=60.0 if task == "velocity" else 20.0)
    base.update(kw)
    return Scenario(**base)


CASES = [
    # overlapping events, one starting inside the start-up, sensor noise
    _scenario("velocity", ((1.8, 0.05, 0.3), (2.5, 0.25, 0.6), (0.9, 0.9, 1.0)), (1e-5, 1e-4, 2e3, 1e-10),
              reference=multisine([0.4, 0.3], [3.0, 11.0], [0.2, 1.0], 0.1)),
    # an event of amplitude 0 (its window still counts), a step reference with the paper's start, no noise
    _scenario("position", ((0.0, 0.4, 0.5), (3.6, 0.7, 0.8)), (0.0, 0.0, 0.0, 0.0),
              reference=step(0.5, 0.1), bumpless=False, estimator="eso", observer_hz=1000.0, ref_accel=100.0),
    # an event running past the end, noise on x1 only
    _scenario("position", ((1.2, 0.95, 5.0),), (1e-5, 0.0, 0.0, 0.0), estimator="eso", observer_hz=1000.0),
]


@pytest.mark.parametrize("sc", CASES, ids=["velocity-overlap-noise", "position-zero-amplitude", "position-tail"])
def test_class_accumulators_match_a_full_rate_log(sc):
    traj = simulate(sc)
    assert not traj.diverged and len(traj.t) == sc.n_steps  # one log row per control period
    got = traj.metrics()
    want = _reference_metrics(traj)
    for k, v in want.items():
        assert got[k] == pytest.approx(float(v), rel=1e-12, abs=0.0), k
    assert got["steps_startup"] + got["steps_disturbance"] + got["steps_tracking"] == got["steps"]
    if any(sc.noise_std):  # V rises and falls from period to period: the count sees both outcomes
        assert 0.1 < got["v_decrease"] < 0.9


def test_an_episode_without_friction_has_no_disturbance_class():
    m = simulate(_scenario("velocity", (), (0.0,) * 4, t_end=0.5)).metrics()
    assert m["steps_disturbance"] == 0 and math.isnan(m["dst_peak"]) and math.isnan(m["dst_iae"])
    assert math.isfinite(m["trk_rmse"]) and m["steps_tracking"] == m["steps"] - m["steps_startup"]


events = strategies.lists(strategies.tuples(strategies.floats(0.0, 3.6), strategies.floats(0.0, 0.6),
                                           strategies.floats(0.001, 0.4)), max_size=4)


@settings(max_examples=25, deadline=None)
@given(events)
def test_the_windows_partition_the_samples(evs):
    """Events drawn at random (amplitude 0 included, overlapping, past the end): every sample lands in exactly one
    window, and each window holds the samples the friction list puts in it."""
    friction = tuple((a, t0, t0 + d) for a, t0, d in evs)
    sc = Scenario(t_end=0.6, control_period=1e-4, substeps=1, log_interval=1e-4, friction=friction, sigma=1e5,
                  smoothing=1e3, current_limit=10.0)
    traj = simulate_batch([sc])[0]
    a = traj.acc
    n = a[layout.M_SU_STEPS] + a[layout.M_DST_STEPS] + a[layout.M_TRK_STEPS]
    assert n == a[layout.M_STEPS] == sc.n_steps
    su, dst, trk = _windows(traj.t, friction)
    assert (a[layout.M_SU_STEPS], a[layout.M_DST_STEPS], a[layout.M_TRK_STEPS]) == (su.sum(), dst.sum(), trk.sum())
