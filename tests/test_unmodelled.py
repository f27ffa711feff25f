"""The servo valve and sensors the law's model leaves out: each effect against an independent reference.

- the play (hysteresis) operator against a plain-Python backlash written from its branch definition, and its loop
  width on a triangle input; through the env the valve opening's loop widens by exactly K h;
- the dead band: from rest, no valve motion for any current below the threshold;
- the sensor delay: the controller's measured output equals the true output d samples earlier (noise off);
- the encoder quantisation: measured values on the grid, within half a step of the true ones;
- the validation errors, the env's randomisation option and the unmodelled suite's draw;
- all effects off: the kernels return their inputs bit for bit and the new state slots stay 0.
"""

from __future__ import annotations

import math
from dataclasses import asdict

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ehss_gym.core.layout import L_X, L_YE, MAX_DELAY, N_LOOP, N_PLANT, X_AV, X_OMEGA, X_THETA, Z_DELAY, Z_PLAY
from ehss_gym.core.params import PlantParams
from ehss_gym.core.scenarios import DEFAULT_DISTRIBUTION, UNMODELLED_DISTRIBUTION, sample_scenario
from ehss_gym.core.settings import C_DELAY, C_HYSTERESIS, C_POS_STEP, C_THRESHOLD, C_VEL_STEP, N_CTRL, Scenario
from ehss_gym.core.sim import simulate
from ehss_gym.core.unmodelled import DATASHEET_RANGES, NONE, Unmodelled, draw_unmodelled
from ehss_gym.core.unmodelled_kernels import dead_band, play, quantise, sense_unmodelled, valve_input
from ehss_gym.envs import EHSSTrackingEnv, EnvConfig

FINITE = st.floats(-50.0, 50.0, allow_nan=False)


def backlash_reference(inputs, width, y0=0.0):
    """Plain-Python backlash written from its two branches: the output follows the input at u - width/2 while the
    input rises past the upper edge, at u + width/2 while it falls past the lower edge, and keeps its value between."""
    out, y = [], y0
    for u in inputs:
        upper_edge, lower_edge = y + width / 2, y - width / 2
        if u >= upper_edge:
            y = u - width / 2
        elif u <= lower_edge:
            y = u + width / 2
        out.append(y)
    return out


def _ctrl(threshold=0.0, hysteresis=0.0, delay=0, pos_step=0.0, vel_step=0.0):
    row = np.zeros(N_CTRL)
    row[C_THRESHOLD], row[C_HYSTERESIS], row[C_DELAY] = threshold, hysteresis, delay
    row[C_POS_STEP], row[C_VEL_STEP] = pos_step, vel_step
    return row


# --- the play operator ---------------------------------------------------------------------------------------------


@settings(max_examples=60, deadline=None)
@given(st.lists(FINITE, min_size=1, max_size=60), st.floats(0.0, 5.0))
def test_the_valves_play_operator_is_the_backlash_of_its_branch_definition(inputs, width):
    z = np.zeros(N_LOOP)
    ctrl = _ctrl(hysteresis=width)
    got = [valve_input(z, u, ctrl) for u in inputs]
    assert np.allclose(got, backlash_reference(inputs, width), rtol=0.0, atol=1e-12)


@pytest.mark.parametrize("width", [0.05, 0.3, 1.0])
def test_a_triangle_input_traces_a_hysteresis_loop_of_the_set_width(width):
    """Up and down a triangle from -A to A, after the first rise: at each input level the falling branch's output
    exceeds the rising branch's by the width h (the datasheet's hysteresis)."""
    amplitude, n = 5.0, 400
    up = np.linspace(-amplitude, amplitude, n)
    tri = np.concatenate([up, up[::-1], up, up[::-1]])
    y, out = 0.0, []
    for u in tri:
        y = play(y, u, 0.5 * width)
        out.append(y)
    out = np.asarray(out)
    rise, fall = out[2 * n:3 * n], out[3 * n:4 * n][::-1]  # the second cycle, both on the levels of ``up``
    inner = np.abs(up) < amplitude - width  # away from the turning points, where the output is on a branch
    assert np.allclose(fall[inner] - rise[inner], width, rtol=0.0, atol=1e-12)
    assert np.allclose(rise[inner], up[inner] - width / 2, atol=1e-12)


def _direct_env(um: Unmodelled, seconds: float):
    env = EHSSTrackingEnv(mode="direct", agent_period=1, episode_seconds=seconds)
    sc = env.unwrapped.scenario_template.replace(friction=(), noise_std=(0.0,) * 4, t_end=seconds, unmodelled=um)
    env.reset(options={"scenario": sc})
    return env


def _x4_on_a_triangle(um: Unmodelled, amplitude=2.0, period=2.0):
    """Drive the valve open loop (direct mode) with a triangle current; x4 [m^2] where the current crosses 0 going up
    and going down in its second cycle."""
    env = _direct_env(um, 2.0 * period)
    h = env.unwrapped.config.control_period
    n = int(round(period / h))
    k = np.arange(2 * n)
    u = amplitude * (2.0 * np.abs(2.0 * ((k / n + 0.75) % 1.0) - 1.0) - 1.0)  # starts at 0, rising
    x4 = []
    for uk in u:
        env.step(np.array([uk / env.unwrapped.config.residual_scale], dtype=np.float32))
        x4.append(env.unwrapped._lanes.z[0, X_AV])
    x4 = np.asarray(x4)
    up_cross, down_cross = n + 0, n + n // 2  # u = 0 rising at k = n, falling half a period later
    return x4[up_cross], x4[down_cross], u[up_cross], u[down_cross]


def test_the_plants_valve_opening_loop_widens_by_k_times_the_hysteresis():
    """Through the env's loop (the valve's lag and the held currents included): the valve's lag alone makes a loop
    in x4 on a triangle; the play operator widens it by exactly K h, because the lag is linear (measured a quarter
    period, 50 time constants, after each turn, where the turn's transient has died out)."""
    K = PlantParams().K
    h_pct = 3.0
    width = h_pct / 100.0 * 10.0  # [mA] 3 % of the 10 mA rated current
    up0, down0, _, _ = _x4_on_a_triangle(NONE)
    up1, down1, _, _ = _x4_on_a_triangle(Unmodelled(hysteresis=h_pct))
    assert (down1 - up1) - (down0 - up0) == pytest.approx(K * width, rel=1e-6)


# --- the dead band ---------------------------------------------------------------------------------------------------


@settings(max_examples=6, deadline=None)
@given(st.lists(st.floats(-0.999, 0.999), min_size=5, max_size=5), st.floats(0.05, 1.0), st.sampled_from([0.0, 1.0]))
def test_from_rest_the_valve_does_not_move_for_any_current_below_the_threshold(fractions, threshold_pct, hyst_pct):
    th = threshold_pct / 100.0 * 10.0  # [mA]
    env = _direct_env(Unmodelled(threshold=threshold_pct, hysteresis=hyst_pct), 0.05)
    scale = env.unwrapped.config.residual_scale
    for f in fractions * 20:
        env.step(np.array([f * th / scale], dtype=np.float32))
        assert env.unwrapped._lanes.z[0, X_AV] == 0.0
    past = th + 0.5 * hyst_pct / 100.0 * 10.0 + 0.1  # [mA] past the threshold and half the play: it moves
    env.step(np.array([past / scale], dtype=np.float32))
    assert env.unwrapped._lanes.z[0, X_AV] > 0.0


@settings(max_examples=80, deadline=None)
@given(FINITE, st.floats(0.0, 5.0))
def test_the_dead_band_is_zero_inside_and_continuous_outside(u, th):
    v = dead_band(u, th)
    if abs(u) <= th:
        assert v == 0.0
    else:
        assert v == pytest.approx(u - math.copysign(th, u), abs=1e-12)
        assert abs(v) <= abs(u) and v * u >= 0.0
    assert abs(dead_band(th + 1e-9, th)) < 2e-9 and abs(dead_band(-th - 1e-9, th)) < 2e-9  # no jump at the edges


# --- the sensor delay and the quantisation ----------------------------------------------------------------------------


def _sampled(task: str, um: Unmodelled, t_end=0.03):
    tmpl = EnvConfig.from_kwargs({"task": task}).template()
    sc = tmpl.replace(t_end=t_end, log_interval=tmpl.control_period, noise_std=(0.0,) * 4, unmodelled=um)
    tr = simulate(sc)
    y_true = tr.log[:, L_X + (X_THETA if task == "position" else X_OMEGA)]
    return tr.log[:, L_YE], y_true


@settings(max_examples=8, deadline=None)
@given(st.integers(1, MAX_DELAY), st.sampled_from(["velocity", "position"]))
def test_the_controller_sees_the_true_output_d_samples_late(d, task):
    y_meas, y_true = _sampled(task, Unmodelled(delay=d))
    assert np.array_equal(y_meas[d:], y_true[:-d])
    assert np.all(y_meas[:d] == y_true[0])  # before the first sample, the plant was at rest at its initial state
    assert np.any(y_true[d:] != y_true[:-d])  # the output moved: the check can fail


@pytest.mark.parametrize("task, um, step", [
    ("position", Unmodelled(encoder_counts=2**16), 2.0 * math.pi / 2**16),
    ("position", Unmodelled(encoder_counts=5000), 2.0 * math.pi / 5000),
    ("velocity", Unmodelled(velocity_step=1e-3), 1e-3),
])
def test_the_measured_output_is_on_the_grid_within_half_a_step(task, um, step):
    y_meas, y_true = _sampled(task, um, t_end=0.1)
    counts = y_meas / step
    assert np.allclose(counts, np.round(counts), rtol=0.0, atol=1e-6)
    assert np.all(np.abs(y_meas - y_true) <= step / 2 * (1 + 1e-9))
    assert len(np.unique(counts.round())) > 3  # the output crossed several counts


@settings(max_examples=100, deadline=None)
@given(st.floats(-1e3, 1e3, allow_nan=False), st.floats(1e-7, 1.0))
def test_quantise_rounds_to_the_nearest_multiple(x, q):
    v = quantise(x, q)
    assert abs(v - x) <= q / 2 * (1 + 1e-9) + 1e-12 * abs(x)
    assert abs(v / q - round(v / q)) < 1e-6


# --- all off: bit for bit -------------------------------------------------------------------------------------------


@settings(max_examples=60, deadline=None)
@given(FINITE, st.lists(FINITE, min_size=N_PLANT, max_size=N_PLANT), st.integers(0, 10))
def test_with_every_effect_off_the_kernels_return_their_inputs_bit_for_bit(u, xm, k):
    z = np.zeros(N_LOOP)
    ctrl = _ctrl()
    assert valve_input(z, u, ctrl) == u
    x = np.asarray(xm, dtype=float)
    sense_unmodelled(z, x, k, ctrl)
    assert np.array_equal(x, np.asarray(xm, dtype=float))
    assert not z.any()


def test_with_every_effect_off_the_new_state_slots_stay_zero_over_a_run():
    tmpl = EnvConfig.from_kwargs({"task": "velocity"}).template().replace(t_end=0.02)
    env = EHSSTrackingEnv(episode_seconds=0.02)
    env.reset(options={"scenario": tmpl})
    for _ in range(20):
        env.step(np.array([0.3], dtype=np.float32))
    z = env.unwrapped._lanes.z[0]
    assert z[Z_PLAY] == 0.0 and not z[Z_DELAY:].any()
    assert not env.unwrapped._lanes.ctrl[0, C_THRESHOLD:C_VEL_STEP + 1].any()


def test_the_default_training_draw_has_no_unmodelled_effects_and_the_option_leaves_the_rest_unchanged():
    tmpl = EnvConfig.from_kwargs({"task": "velocity"}).template()
    for seed in range(5):
        plain = sample_scenario(seed, tmpl, dist=DEFAULT_DISTRIBUTION)
        with_um = sample_scenario(seed, tmpl, dist=UNMODELLED_DISTRIBUTION)
        assert plain.unmodelled == NONE
        assert with_um.unmodelled == draw_unmodelled(seed) and not with_um.unmodelled.off
        assert np.array_equal(with_um.reference.spec, plain.reference.spec)
        assert with_um.replace(unmodelled=NONE, reference=plain.reference) == plain


# --- ranges, validation, the env option, the suite ------------------------------------------------------------------


def test_the_drawn_effects_lie_in_the_stated_ranges():
    r = DATASHEET_RANGES
    for seed in range(200):
        um = draw_unmodelled(seed)
        assert r.threshold[0] <= um.threshold <= r.threshold[1] <= 0.5
        assert r.hysteresis[0] <= um.hysteresis <= r.hysteresis[1] <= 3.0
        assert r.delay[0] <= um.delay <= r.delay[1]
        assert um.encoder_counts in [2**b for b in range(r.encoder_bits[0], r.encoder_bits[1] + 1)]
        assert r.velocity_step[0] <= um.velocity_step <= r.velocity_step[1]


@pytest.mark.parametrize("field, value, match", [
    ("threshold", -0.1, r"unmodelled\.threshold must be in \[0, 10\]"),
    ("threshold", math.nan, r"unmodelled\.threshold must be a finite number"),
    ("hysteresis", 31.0, r"unmodelled\.hysteresis must be in \[0, 30\]"),
    ("delay", MAX_DELAY + 1, rf"unmodelled\.delay \(control samples\) must be an integer in \[0, {MAX_DELAY}\]"),
    ("delay", 1.5, r"unmodelled\.delay"),
    ("encoder_counts", 2, r"unmodelled\.encoder_counts must be 0 \(off\) or an integer in \[4, "),
    ("encoder_counts", True, r"unmodelled\.encoder_counts"),
    ("velocity_step", 11.0, r"unmodelled\.velocity_step must be in \[0, 10\]"),
    ("rated_current", 0.0, r"unmodelled\.rated_current must be in \(0, inf\)"),
])
def test_a_bad_effect_size_raises_naming_the_field_and_its_range(field, value, match):
    with pytest.raises(ValueError, match=match):
        Unmodelled(**{field: value})


def test_the_scenario_and_the_env_check_their_unmodelled_settings():
    with pytest.raises(ValueError, match="unmodelled must be an ehss_gym.core.unmodelled.Unmodelled"):
        Scenario(unmodelled={"delay": 1})
    with pytest.raises(ValueError, match="unmodelled_effects must be True or False"):
        EnvConfig.from_kwargs({"unmodelled_effects": "yes"})


def test_the_env_option_draws_effects_per_episode_and_is_off_by_default():
    env = EHSSTrackingEnv()
    _, info = env.reset(seed=3)
    assert info["scenario"]["unmodelled"] == asdict(NONE)
    env = EHSSTrackingEnv(unmodelled_effects=True)
    seen = set()
    for s in range(3):
        _, info = env.reset(seed=s)
        um = env.unwrapped._lanes.scenarios[0].unmodelled
        assert um == draw_unmodelled(info["scenario_seed"]) and not um.off
        assert env.unwrapped._lanes.ctrl[0, C_DELAY] == um.delay
        seen.add(um)
        env.step(np.zeros(1, dtype=np.float32))
    assert len(seen) == 3


def test_a_share_of_the_episodes_has_the_effects_the_same_ones_and_the_rest_none():
    """unmodelled_share s: about s of the training episodes have the effects (binomial: 400 episodes at s = 0.5 give
    200 +- 40 at 4 standard deviations), each the effects it has at share 1; the validation draw follows the env's."""
    from dataclasses import replace

    from ehss_gym.core.scenarios import unmodelled_distribution
    from ehss_gym.evaluation.heldout import heldout_suite

    assert unmodelled_distribution(1.0) is UNMODELLED_DISTRIBUTION
    half = replace(DATASHEET_RANGES, share=0.5)
    draws = [draw_unmodelled(seed, half) for seed in range(400)]
    kept = [(seed, um) for seed, um in enumerate(draws) if not um.off]
    assert 160 <= len(kept) <= 240 and all(um == NONE for um in draws if um.off)
    assert all(um == draw_unmodelled(seed) for seed, um in kept)
    env = EHSSTrackingEnv(unmodelled_effects=True, unmodelled_share=0.5)
    offs = []
    for s in range(12):
        _, info = env.reset(seed=s)
        um = env.unwrapped._lanes.scenarios[0].unmodelled
        assert um == draw_unmodelled(info["scenario_seed"], half)
        offs.append(um.off)
    assert 0 < sum(offs) < 12
    suite = heldout_suite({"unmodelled_effects": True, "unmodelled_share": 0.5}, 12, 0)
    assert 0 < sum(sc.unmodelled.off for sc in suite) < 12
    for bad in (0.0, 1.5, math.nan):
        with pytest.raises(ValueError, match=r"unmodelled_share must be"):
            EnvConfig.from_kwargs({"unmodelled_effects": True, "unmodelled_share": bad})
        with pytest.raises(ValueError, match=r"unmodelled share must be"):
            replace(DATASHEET_RANGES, share=bad)


def test_the_unmodelled_suite_draws_held_out_episodes_with_effects():
    from ehss_gym.core.scenarios import TRAIN_SEED_LIMIT
    from ehss_gym.evaluation.suites import EvalConfig, build_episodes

    eps = build_episodes(EvalConfig(suites=("heldout", "unmodelled"), tasks=("velocity",), heldout_episodes=3))
    held = [e for e in eps if e.suite == "heldout"]
    unm = [e for e in eps if e.suite == "unmodelled"]
    assert len(unm) == 3 and all(not e.physical["unmodelled"].off for e in unm)
    assert all(e.physical["unmodelled"] == NONE for e in held)
    assert all(e.scenario_seed >= TRAIN_SEED_LIMIT for e in unm)
    assert not {e.scenario_seed for e in unm} & {e.scenario_seed for e in held}
