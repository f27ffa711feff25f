"""The compensators of the unmodelled valve and sensors (loop settings ``reference_delay``, ``inverse_threshold``,
``inverse_hysteresis``): each against what it must achieve, checked on a path it does not share.

- the valve inverse: for any command sequence, the valve of :mod:`ehss_gym.core.unmodelled_kernels` (the play
  operator tested against a plain backlash in test_unmodelled) driven by the inverse's current puts out the command
  itself (to rounding); in the closed loop, a valve with threshold and hysteresis behind the inverse at its true
  parameters moves the plant as the loop without them does;
- the reference delay: at every control sample the law's errors are the estimator's values minus the reference
  model's logged outputs of d samples before (exactly for a whole d, interpolated for a fractional one), every
  derivative alike; in the closed loop with a sensor delay of d samples, it brings the position task's tracking error
  back to the loop without the delay;
- both off: the defaults, bit for bit (also ``tools/loop_fingerprint.py``); bad values name the setting;
- the ideal corrections' sizes (``ehss headroom``) against their first-order and bounding values.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ehss_gym.core.compensators import inverse_model_update, valve_inverse
from ehss_gym.core.layout import L_E, L_X, L_YD, L_YE, N_LOOP
from ehss_gym.core.rig import as_rig
from ehss_gym.core.scenarios import UNMODELLED_DISTRIBUTION, heldout_scenarios, sample_scenario
from ehss_gym.core.settings import (
    C_HYSTERESIS,
    C_INV_HYSTERESIS,
    C_INV_THRESHOLD,
    C_THRESHOLD,
    N_CTRL,
    Scenario,
    ctrl_row,
)
from ehss_gym.core.sim import simulate, simulate_batch
from ehss_gym.core.unmodelled import Unmodelled
from ehss_gym.core.unmodelled_kernels import valve_input
from ehss_gym.envs import EHSSTrackingEnv, EnvConfig
from ehss_gym.evaluation.suites import EvalConfig, build_episodes
from ehss_gym.study.corrections import episode_corrections, valve_known

COMMANDS = st.lists(st.floats(-8.0, 8.0, allow_nan=False), min_size=1, max_size=80)


@settings(max_examples=80, deadline=None)
@given(COMMANDS, st.floats(0.0, 0.5), st.floats(0.0, 1.0))
def test_the_valve_behind_its_inverse_puts_out_the_command(commands, threshold, hysteresis):
    """threshold [mA], hysteresis [mA] (the play's total width): the valve's input (its play operator's output) equals
    each command to rounding, whatever came before."""
    z = np.zeros(N_LOOP)
    ctrl = np.zeros(N_CTRL)
    ctrl[C_THRESHOLD] = ctrl[C_INV_THRESHOLD] = threshold
    ctrl[C_HYSTERESIS] = ctrl[C_INV_HYSTERESIS] = hysteresis
    for v in commands:
        u = valve_inverse(z, v, ctrl)
        assert valve_inverse(z, v, ctrl) == u  # reading the model twice (the env's look-ahead) changes nothing
        out = valve_input(z, u, ctrl)
        inverse_model_update(z, u, ctrl)
        assert out == pytest.approx(v, abs=1e-12)
        assert abs(u - v) <= threshold + 0.5 * hysteresis + 1e-12  # it moves the command by at most th + h/2


def test_the_inverse_of_an_absent_valve_effect_returns_the_command():
    z = np.zeros(N_LOOP)
    ctrl = np.zeros(N_CTRL)
    assert all(valve_inverse(z, v, ctrl) == v for v in (-3.0, 0.0, 1e-9, 7.5))
    inverse_model_update(z, 4.0, ctrl)
    assert not z.any()


def _unmodelled_episodes(task: str, n: int, seconds: float = 1.0) -> list[Scenario]:
    """Held-out episodes of ``task`` at the env's defaults without sensor noise (so that the only effects are those
    set on top)."""
    tmpl = EnvConfig.from_kwargs({"task": task}).template()
    return [sc.replace(noise_std=(0.0,) * 4) for sc in heldout_scenarios(n, tmpl, seconds)]


@pytest.mark.parametrize("task", ["velocity", "position"])
def test_a_valve_with_dead_band_and_hysteresis_behind_its_true_inverse_moves_the_plant_as_without_them(task):
    """The valve's threshold 0.5 % and hysteresis 3 % (its datasheet bounds) with the inverse at those values: on an
    episode that never reaches the current limit the plant's states are those of the loop with neither, to rounding;
    on every episode (the start-up may reach the limit, which the inverse cannot pass) the tracking and disturbance
    metrics are within 1e-3; without the inverse they differ by more. The applied current differs (it carries the
    inverse's jumps)."""
    scs = _unmodelled_episodes(task, 6)
    um = Unmodelled(threshold=0.5, hysteresis=3.0)
    plain = simulate_batch(scs)
    valve = simulate_batch([sc.replace(unmodelled=um) for sc in scs])
    inv = simulate_batch([sc.replace(unmodelled=um, inverse_threshold=0.5, inverse_hysteresis=3.0) for sc in scs])
    unsaturated = 0
    for p, v, i in zip(plain, valve, inv):
        mp, mv, mi = p.metrics(), v.metrics(), i.metrics()
        assert not i.diverged
        if math.isfinite(mp["trk_rmse"]):  # (an episode whose friction windows cover it has no tracking window)
            assert mi["trk_rmse"] == pytest.approx(mp["trk_rmse"], rel=1e-3)
            assert abs(mv["trk_rmse"] / mp["trk_rmse"] - 1.0) > 1e-2  # the effects do matter
        assert mi["tv_u_rate"] > mp["tv_u_rate"]  # the inverse's current jumps
        if mp["saturation"] == 0.0 and mi["saturation"] == 0.0:
            unsaturated += 1
            scale = np.abs(p.log[:, L_X:L_X + 4]).max(axis=0)
            assert np.all(np.abs(i.log[:, L_X:L_X + 4] - p.log[:, L_X:L_X + 4]) <= 1e-12 * scale)
    assert unsaturated >= (1 if task == "position" else 0)


def test_on_a_rig_of_another_rated_current_the_valve_and_its_inverse_are_sized_on_that_current():
    """On the compact 140 bar rig (rated current 15 mA) the valve drawn with the unmodelled effects (the env's
    training draw and the unmodelled suite) has its threshold and hysteresis in percent of 15 mA, and the inverse at
    the same percentages cancels it: the plant moves as without both, to rounding. Sized on Table I's 10 mA, the inverse
    would leave a third of the valve's dead band and play in the loop."""
    rig, laws = as_rig("compact140"), "reports/servo/baselines/law_settings.json"  # the rig's tuned law
    laws = str(Path(__file__).resolve().parents[1] / laws)
    tmpl = EnvConfig.from_kwargs({"task": "position", "plant": rig, "law_settings": laws}).template()
    ev = [e for e in build_episodes(EvalConfig(tasks=("position",), suites=("unmodelled",), heldout_episodes=2,
                                               plant=rig, law_settings=laws)) if e.suite == "unmodelled"]
    assert tmpl.rated_current == rig.rated_current == 15.0
    drawn = sample_scenario(7, tmpl, 0.5, UNMODELLED_DISTRIBUTION).unmodelled
    assert drawn.rated_current == 15.0 and drawn.threshold_current == pytest.approx(drawn.threshold * 0.15)
    assert len(ev) == 2 and all(e.physical["unmodelled"].rated_current == 15.0 for e in ev)
    for e in ev:  # the headroom's valve-knowing oracle gives the valve's own percentages on this rig too
        um = e.physical["unmodelled"]
        assert valve_known(e.physical) == pytest.approx({"inverse_threshold": um.threshold,
                                                         "inverse_hysteresis": um.hysteresis})
    row = ctrl_row(tmpl.replace(inverse_threshold=0.5, inverse_hysteresis=3.0))
    assert (row[C_INV_THRESHOLD], row[C_INV_HYSTERESIS]) == pytest.approx((0.075, 0.45))
    um = replace(drawn, delay=0, encoder_counts=0, velocity_step=0.0)  # the valve alone
    unsaturated = 0
    for seed in range(6):  # (an episode whose start-up reaches the limit: the inverse cannot pass it)
        sc = sample_scenario(seed, tmpl, 0.4).replace(noise_std=(0.0,) * 4)
        plain, inv = simulate_batch([sc, sc.replace(unmodelled=um, inverse_threshold=um.threshold,
                                                     inverse_hysteresis=um.hysteresis)])
        if plain.metrics()["saturation"] == 0.0 and inv.metrics()["saturation"] == 0.0:
            unsaturated += 1
            scale = np.abs(plain.log[:, L_X:L_X + 4]).max(axis=0)
            assert np.all(np.abs(inv.log[:, L_X:L_X + 4] - plain.log[:, L_X:L_X + 4]) <= 1e-12 * scale), seed
    assert unsaturated >= 1


def test_a_valve_sized_on_another_rated_current_than_the_scenarios_is_refused_by_name():
    """One valve: a scenario whose valve effects are percent of another rated current than its own is an error naming
    both, not a valve silently sized on Table I's 10 mA; a valve without threshold or hysteresis needs none."""
    sc = Scenario(rated_current=15.0)
    with pytest.raises(ValueError, match=r"unmodelled.rated_current \(10 mA\) must be the scenario's rated_current "
                                         r"\(15 mA, the rig's\).*Unmodelled\(\.\.\., rated_current=15\)"):
        sc.replace(unmodelled=Unmodelled(threshold=0.3))
    assert sc.replace(unmodelled=Unmodelled(threshold=0.3, rated_current=15.0)).unmodelled.threshold_current == \
        pytest.approx(0.045)
    assert sc.replace(unmodelled=Unmodelled(delay=2)).unmodelled.delay == 2  # no valve effect: no current involved
    with pytest.raises(ValueError, match=r"rated_current \(mA\) must be"):
        Scenario(rated_current=0.0)


@pytest.mark.parametrize(("task", "delay"), [("velocity", 2.0), ("position", 1.0), ("position", 3.0), ("velocity", 1.5),
                                             ("position", 2.25)])
def test_the_laws_errors_are_against_the_reference_model_of_d_samples_before(task, delay):
    """Logged at every control sample: e^(i)_k = y_e^(i)_k - y_d^(i)(k - d) for every derivative i < m, y_d from the
    same log (before the first sample: the first sample's values); a fractional d = j + f interpolates samples k - j
    and k - j - 1."""
    sc = _unmodelled_episodes(task, 1, 0.3)[0]
    h = sc.control_period
    tr = simulate(sc.replace(reference_delay=delay, log_interval=h))
    m = sc.order
    yd, ye, e = tr.log[:, L_YD:L_YD + m], tr.log[:, L_YE:L_YE + m], tr.log[:, L_E:L_E + m]
    j, f = int(delay), delay - int(delay)
    k = np.arange(len(yd))
    a, b = yd[np.maximum(k - j, 0)], yd[np.maximum(k - j - 1, 0)]
    want = ye - (a if f == 0.0 else a + f * (b - a))
    if f == 0.0:
        assert np.array_equal(e, want)
    else:
        assert np.allclose(e, want, rtol=1e-12, atol=1e-12 * np.abs(want).max())
    assert np.abs(e - (ye - yd)).max() > 0.0  # the law's errors do differ from today's


def test_the_reference_delay_brings_back_the_position_tracking_a_sensor_delay_takes():
    """Position task, noise-free held-out episodes: a sensor delay of 2 samples multiplies the tracking RMSE (the true
    output leads y_d); the law's reference delayed by those 2 samples brings it back to within 10 % of the loop
    without the delay (the ruler still measures the true output against today's y_d)."""
    scs = _unmodelled_episodes("position", 4, 2.0)
    um = Unmodelled(delay=2)
    none = [t.metrics()["trk_rmse"] for t in simulate_batch(scs)]
    late = [t.metrics()["trk_rmse"] for t in simulate_batch([sc.replace(unmodelled=um) for sc in scs])]
    comp = [t.metrics()["trk_rmse"] for t in simulate_batch([sc.replace(unmodelled=um, reference_delay=2)
                                                              for sc in scs])]
    assert np.all(np.isfinite(none))
    assert np.median(late) > 5.0 * np.median(none)
    assert np.median(comp) == pytest.approx(np.median(none), rel=0.1)


def test_off_is_the_default_loop_bit_for_bit():
    env_a = EHSSTrackingEnv(task="position")
    env_b = EHSSTrackingEnv(task="position", reference_delay=0.0, inverse_threshold=0.0, inverse_hysteresis=0.0)
    oa, _ = env_a.reset(seed=3)
    ob, _ = env_b.reset(seed=3)
    assert np.array_equal(oa, ob)
    for k in range(40):
        act = np.array([0.2 * math.sin(k)], np.float32)
        sa, sb = env_a.step(act), env_b.step(act)
        assert np.array_equal(sa[0], sb[0]) and sa[1] == sb[1]


@pytest.mark.parametrize(("kw", "match"), [({"reference_delay": -1.0}, "reference_delay"),
                                           ({"reference_delay": 9.0}, "reference_delay"),
                                           ({"inverse_threshold": 11.0}, "inverse_threshold"),
                                           ({"inverse_hysteresis": -0.1}, "inverse_hysteresis"),
                                           ({"inverse_hysteresis": math.nan}, "inverse_hysteresis")])
def test_bad_compensator_settings_name_the_setting_and_its_range(kw, match):
    with pytest.raises(ValueError, match=match):
        Scenario(**kw)
    with pytest.raises(ValueError, match=match):
        EHSSTrackingEnv(**kw)


def test_the_ideal_corrections_sizes_follow_from_their_definitions():
    """On one unmodelled-suite episode per task: the reference shift of a delay of d samples is, to first order, d h
    times the reference's next derivative (its RMS within 5 %); the valve inverse adds at most th + h/2 to the law's
    current, and about that much on the average (its RMS within [th, th + h/2]) when the current keeps moving."""
    for task in ("velocity", "position"):
        ep = build_episodes(EvalConfig(suites=("unmodelled",), tasks=(task,), heldout_episodes=1))[0]
        um = ep.physical["unmodelled"]
        got = episode_corrections(task, {"task": task}, ep.physical)
        tr = simulate(EnvConfig.from_kwargs({"task": task}).template().replace(**ep.physical).replace(
            log_interval=5e-5, reference_delay=float(um.delay)))
        sel = tr.log[:, 0] >= 0.2
        slope = um.delay * 5e-5 * np.sqrt(np.mean(tr.log[sel, L_YD + 1] ** 2))
        ss, n, _ = got["reference shift y_d"]
        assert math.sqrt(ss / n) == pytest.approx(slope, rel=0.05)
        ss, n, peak = got["valve inverse's added current"]
        th, half = um.threshold_current, 0.5 * um.hysteresis_current
        assert peak <= th + half + 1e-12 and th <= math.sqrt(ss / n) <= th + half
