"""The action modes (env setting ``action``): zero action = the base law bit for bit, the vector env = the single env,
the checkers, the bounds, and each mode against an independent derivation of what it should do."""

from __future__ import annotations

import math
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import solve_ivp
from stable_baselines3.common.env_checker import check_env as sb3_check_env

from ehss_gym import sine
from ehss_gym.core.filters import butterworth_coefficients
from ehss_gym.core.layout import I_SHIFT, I_URES, I_YD, MAX_DELAY
from ehss_gym.core.settings import (
    C_DOB_GAIN,
    C_INV_HYSTERESIS,
    C_INV_THRESHOLD,
    C_LAYER_GAIN,
    C_REF_DELAY,
    C_SHIFT,
    C_SIGMA,
    C_SMOOTH,
)
from ehss_gym.core.unmodelled import Unmodelled
from ehss_gym.envs import EHSSTrackingEnv, EHSSTrackingVectorEnv, EnvConfig
from ehss_gym.envs import lanes as lanes_mod
from ehss_gym.envs.actions import ACTION_NAMES, FILTER_TAU, RATE_TIME, SCHEDULE_RANGES, action_mode
from ehss_gym.envs.buffers import F_ACT, F_URES, H_CTRL, H_PEEK, HOT_BLOCKS, N_ACT
from ehss_gym.envs.lanes import hot_block

MODES = [m for m in ACTION_NAMES if m != "current"]
# the settings a mode needs beyond the env's defaults: the compensation mode scales the loop's compensators
COMPENSATORS = {"reference_delay": 1.0, "inverse_threshold": 0.375, "inverse_hysteresis": 2.25}
NEEDS = {"compensation": COMPENSATORS}
SHORT = 0.02  # [s]
# the residual agents' rewards (the class and the physical reward) and memory, so that their terms are compared too
RECIPE = {"agent_period": 20, "memory_tau": 0.1, "unmodelled_effects": True,
          "reward_weights": {"track": 0.0, "effort": 0.0, "rate": 0.0, "class": 1.0, "physical": 1.0,
                             "saturation": 1.0}}


def _k(env) -> int:
    return env.action_space.shape[-1]


@pytest.mark.parametrize("task", ["velocity", "position"])
@pytest.mark.parametrize("mode", MODES)
def test_zero_action_is_the_base_law_bit_for_bit(task, mode):
    """Every mode with a = 0 throughout gives the current mode's zero-action episodes: observations (today's entries),
    rewards, infos and the episode's metrics, byte for byte (with the observer on, so the schedule's third entry and the
    observer's gain are exercised)."""
    kw = {**RECIPE, "task": task, "episode_seconds": 0.3, "dob_hz": 20.0, **NEEDS.get(mode, {})}
    base = EHSSTrackingVectorEnv(3, **kw)
    other = EHSSTrackingVectorEnv(3, action=mode, **kw)
    D = base.single_observation_space.shape[0]
    ob, _ = base.reset(seed=5)
    oo, _ = other.reset(seed=5)
    assert np.array_equal(ob, oo[:, :D])
    for _ in range(40):  # past the episodes' ends: the autoreset is part of it
        ob, rb, tb, trb, ib = base.step(np.zeros((3, 1), dtype=np.float32))
        oo, ro, to, tro, io = other.step(np.zeros((3, _k(other)), dtype=np.float32))
        assert np.array_equal(ob, oo[:, :D]) and np.array_equal(rb, ro) and np.all(np.isfinite(ro))
        assert np.array_equal(tb, to) and np.array_equal(trb, tro)
        for key in ("u_applied", "u_base", "e", "s", "V"):
            assert np.array_equal(ib[key], io[key]), key
        if "metrics" in ib:
            for i in np.flatnonzero(ib["_metrics"]):
                assert ib["metrics"][i] == io["metrics"][i]


def _vector_against_singles(kw: dict, n: int, steps: int, seed: int) -> int:
    venv = EHSSTrackingVectorEnv(n, **kw)
    envs = [EHSSTrackingEnv(**kw) for _ in range(n)]
    obs, _ = venv.reset(seed=seed)
    assert np.array_equal(obs, np.stack([e.reset(seed=seed + i)[0] for i, e in enumerate(envs)]))
    rng = np.random.default_rng(seed)
    pending = [False] * n
    ends = 0
    for _ in range(steps):
        A = rng.uniform(-1.2, 1.2, (n, _k(venv))).astype(np.float32)
        o, r, te, tr, info = venv.step(A)
        for i, e in enumerate(envs):
            if pending[i]:
                so, _ = e.reset()
                sr, ste, s_tr, pending[i] = 0.0, False, False, False
            else:
                so, sr, ste, s_tr, si = e.step(A[i])
                pending[i] = ste or s_tr
                ends += int(pending[i])
                assert si["clipped"] == info["clipped"][i] and si["u_residual"] == info["u_residual"][i]
            assert np.array_equal(so, o[i]) and sr == r[i] and ste == te[i] and s_tr == tr[i]
    return ends


@pytest.mark.parametrize("mode", MODES)
def test_vector_env_equals_single_envs(mode):
    kw = {"task": "position", "action": mode, "episode_seconds": 0.01, "unmodelled_effects": True, "dob_hz": 20.0,
          **NEEDS.get(mode, {})}
    assert _vector_against_singles(kw, 3, 60, 11) >= 3


@pytest.mark.parametrize("task", ["velocity", "position"])
@pytest.mark.parametrize("mode", MODES)
def test_gymnasium_and_sb3_checkers_pass_without_warnings(task, mode):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        kw = {"task": task, "action": mode, "episode_seconds": SHORT, **NEEDS.get(mode, {})}
        gym_check_env(gym.make("EHSSTracking-v0", **kw).unwrapped)
        sb3_check_env(EHSSTrackingEnv(**kw))


@pytest.mark.parametrize("mode, dob, k, extra", [
    ("current", 0.0, 1, []), ("rate", 0.0, 1, ["action"]), ("filtered", 0.0, 1, ["action"]),
    ("reference", 0.0, 1, ["action", "ref_shift"]), ("schedule", 0.0, 2, ["action_width", "action_sigma", "width"]),
    ("schedule", 20.0, 3, ["action_width", "action_sigma", "action_observer", "width"]),
    ("reference-schedule", 0.0, 3, ["action_shift", "action_width", "action_sigma", "ref_shift", "width"]),
    ("reference-schedule", 20.0, 3, ["action_shift", "action_width", "action_sigma", "ref_shift", "width"]),
    ("compensation", 20.0, 4, ["action_inverse", "action_delay", "action_width", "action_sigma", "width"])])
def test_spaces_and_the_observation_entries_each_mode_adds(mode, dob, k, extra):
    env = EHSSTrackingEnv(task="position", action=mode, dob_hz=dob, episode_seconds=SHORT, **NEEDS.get(mode, {}))
    base = EHSSTrackingEnv(task="position", episode_seconds=SHORT)
    assert env.action_space.shape == (k,)
    names = [e[0] for e in env.observation_layout]
    assert names[:len(base.observation_layout)] == [e[0] for e in base.observation_layout]
    assert names[len(base.observation_layout):] == extra


BAD = [
    ({"action": "torque"}, r"action must be one of \['current', 'rate', 'filtered', 'reference', 'schedule', "
                           r"'reference-schedule', 'compensation'\]"),
    ({"action": "current", "action_bound": 1.0}, r"action_bound applies to the actions \['rate', 'filtered', "
                                                 r"'reference', 'reference-schedule'\].*action 'current' has none"),
    ({"action": "schedule", "action_bound": 1.0}, r"action 'schedule' has none"),
    ({"action": "rate", "action_bound": 0.0}, r"action_bound must be in \(0, inf\)"),
    ({"action": "reference", "mode": "direct"}, r"action 'reference' acts through the law: it needs mode 'residual'"),
    ({"action": "schedule", "mode": "direct"}, r"action 'schedule' acts through the law"),
    ({"action": "reference", "estimator": "analog"}, r"action 'reference' shifts the law's digital reference model"),
    ({"action": "reference-schedule", "mode": "direct"}, r"action 'reference-schedule' acts through the law"),
    ({"action": "reference-schedule", "estimator": "analog"}, r"action 'reference-schedule' shifts the law's digital"),
    ({"action": "compensation"}, r"action 'compensation' scales the loop's compensators: it needs reference_delay, "
                                 r"inverse_threshold or inverse_hysteresis > 0"),
    ({"action": "compensation", "mode": "direct", **COMPENSATORS}, r"action 'compensation' acts through the law"),
]


@pytest.mark.parametrize("kwargs, match", BAD)
def test_bad_action_settings_name_the_setting_and_the_range(kwargs, match):
    with pytest.raises(ValueError, match=match):
        EHSSTrackingEnv(**kwargs)


@pytest.mark.parametrize("mode", MODES)
def test_an_action_is_kept_in_its_own_slots(mode):
    """Every entry of the largest action of a mode lands in the lane's action block (F_ACT), and no other slot of the
    lane's buffer moves when the action changes (a mode with more entries than the block once overwrote the physical
    reward's constants behind it)."""
    env = EHSSTrackingVectorEnv(2, action=mode, dob_hz=20.0, episode_seconds=0.3, **RECIPE | NEEDS.get(mode, {}))
    env.reset(seed=2)
    k = _k(env)
    assert k <= N_ACT
    lanes = env._lanes
    before, hot_before = lanes.F.copy(), lanes.H.copy()
    a = np.full((2, k), 0.5, dtype=np.float32)
    getattr(lanes_mod, action_mode(mode).write)(lanes, np.arange(2), a.astype(np.float64))
    moved = set(np.flatnonzero(np.any(lanes.F != before, axis=0)))
    hot_moved = {off for off, width in HOT_BLOCKS
                 if not np.array_equal(hot_block(lanes.H, 2, off, width), hot_block(hot_before, 2, off, width))}
    # what a mode may move: its action block, the residual, the law's settings (the controller rows) and the
    # look-ahead of the next sample made again with them
    may = set(range(F_ACT, F_ACT + k)) | {F_URES}
    assert moved <= may, sorted(moved - may)
    assert hot_moved <= {H_CTRL, H_PEEK}, sorted(hot_moved - {H_CTRL, H_PEEK})
    assert np.array_equal(lanes.F[:, F_ACT:F_ACT + k], a)


def test_a_wrong_action_shape_or_nan_raises_and_out_of_range_is_clipped_and_counted():
    env = EHSSTrackingEnv(action="schedule", episode_seconds=SHORT)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"action must have shape \(2,\)"):
        env.step(np.zeros(1, dtype=np.float32))
    with pytest.raises(ValueError, match="NaN"):
        env.step(np.array([0.0, np.nan], dtype=np.float32))
    _, _, _, _, info = env.step(np.array([3.0, 0.0], dtype=np.float32))
    assert info["clipped"] and info["n_clipped"] == 1
    ctrl = env.unwrapped._lanes.ctrl[0]
    assert ctrl[C_SMOOTH] == pytest.approx(EnvConfig.from_kwargs({}).smoothing * SCHEDULE_RANGES[0][2], rel=1e-12)
    venv = EHSSTrackingVectorEnv(2, action="rate", episode_seconds=SHORT)
    venv.reset(seed=0)
    with pytest.raises(ValueError, match=r"actions must have shape \(2, 1\)"):
        venv.step(np.zeros((2, 2), dtype=np.float32))


# --- the bounds -------------------------------------------------------------------------------------------------


@settings(max_examples=8, deadline=None)
@given(st.lists(st.floats(-1.5, 1.5), min_size=30, max_size=30), st.sampled_from(["rate", "filtered"]))
def test_the_residual_stays_within_its_authority_and_its_rate_bound(actions, mode):
    """agent_period 1: each step is one control period, so the residual's change per step is per period."""
    env = EHSSTrackingEnv(task="position", action=mode, agent_period=1, episode_seconds=SHORT)
    cfg = env.config
    R = cfg.action_bound
    h = cfg.control_period
    env.reset(seed=1)
    u = 0.0
    for a in actions:
        _, _, _, _, info = env.step(np.array([a], dtype=np.float32))
        du = info["u_residual"] - u
        u = info["u_residual"]
        assert abs(u) <= R
        if mode == "rate":
            assert abs(du) <= h * R / RATE_TIME * (1 + 1e-12)
        else:  # a first-order filter moves towards R a by its step's share
            target = R * min(1.0, max(-1.0, float(np.float32(a))))  # the action as the env got it
            assert du == pytest.approx(-math.expm1(-h / FILTER_TAU) * (target - (u - du)), rel=1e-9, abs=1e-15)


@settings(max_examples=8, deadline=None)
@given(st.lists(st.lists(st.floats(-1.5, 1.5), min_size=3, max_size=3), min_size=5, max_size=5))
def test_the_reference_shift_and_the_schedule_factors_stay_in_their_ranges(actions):
    ref = EHSSTrackingEnv(task="position", action="reference", episode_seconds=SHORT)
    sch = EHSSTrackingEnv(task="position", action="schedule", dob_hz=20.0, episode_seconds=SHORT)
    both = EHSSTrackingEnv(task="position", action="reference-schedule", episode_seconds=SHORT)
    ref.reset(seed=0)
    sch.reset(seed=0)
    both.reset(seed=0)
    base = sch._lanes.ctrl_base
    D = ref.config.action_bound
    for a in actions:
        ref.step(np.array(a[:1], dtype=np.float32))
        sch.step(np.array(a, dtype=np.float32))
        both.step(np.array(a, dtype=np.float32))
        assert abs(ref._lanes.ctrl[0, C_SHIFT]) <= D and abs(both._lanes.ctrl[0, C_SHIFT]) <= D
        for c in (sch._lanes.ctrl[0], both._lanes.ctrl[0]):
            for slot, (_, lo, hi) in ((C_SMOOTH, SCHEDULE_RANGES[0]), (C_LAYER_GAIN, SCHEDULE_RANGES[0]),
                                      (C_SIGMA, SCHEDULE_RANGES[1])):
                assert lo * (1 - 1e-12) <= c[slot] / base[slot] <= hi * (1 + 1e-12)
        c = sch._lanes.ctrl[0]
        f_d = -math.log1p(-c[C_DOB_GAIN]) / (2 * math.pi * sch.config.control_period)  # the observer's bandwidth
        assert SCHEDULE_RANGES[2][1] * (1 - 1e-9) <= f_d / 20.0 <= SCHEDULE_RANGES[2][2] * (1 + 1e-9)


# --- each mode against an independent derivation -------------------------------------------------------------------


def test_a_constant_rate_ramps_the_residual_to_its_authority_and_a_filter_settles_exponentially():
    """Closed forms: the rate mode's residual after k periods of a held a is min(R, k h a R / RATE_TIME); the filtered
    mode's is R a (1 - exp(-k h / tau)), the continuous first-order lag sampled."""
    for mode in ("rate", "filtered"):
        env = EHSSTrackingEnv(task="velocity", action=mode, agent_period=1, episode_seconds=0.05)
        R, h = env.config.action_bound, env.config.control_period
        env.reset(seed=3)
        for k in range(1, 400):
            _, _, _, _, info = env.step(np.array([0.5], dtype=np.float32))
            want = min(R, k * h * 0.5 * R / RATE_TIME) if mode == "rate" else 0.5 * R * -math.expm1(-k * h / FILTER_TAU)
            assert info["u_residual"] == pytest.approx(want, rel=1e-9), (mode, k)


def test_the_reference_shift_is_the_continuous_reference_models_response_to_the_shift():
    """The shift Delta at the samples against the continuous Butterworth reference model (its ODE integrated by
    solve_ivp) driven by the shift's first-order-hold input: 0 before the first sample, ramping to delta over the period
    before it, then held."""
    env = EHSSTrackingEnv(task="position", action="reference", agent_period=1, episode_seconds=0.05)
    cfg = env.config
    h, m, delta = cfg.control_period, cfg.order, 0.7 * cfg.action_bound
    env.reset(seed=0)
    peek = env.unwrapped._lanes.peek
    got = []
    for _ in range(300):
        env.step(np.array([0.7], dtype=np.float32))
        got.append(peek[0, I_SHIFT])  # the shift at the next sample
    c = butterworth_coefficients(m, cfg.template().ref_model_hz)

    def rhs(t, x):
        v = delta * min(1.0, max(0.0, 1.0 + t / h))  # the hold's ramp over [-h, 0]
        return [*x[1:], c[0] * v - float(np.dot(c, x))]

    t = (np.arange(300) + 1) * h
    sol = solve_ivp(rhs, (-h, t[-1]), np.zeros(m), t_eval=t, rtol=1e-11, atol=1e-13 * delta, method="DOP853")
    assert np.allclose(got, sol.y[0], rtol=1e-7, atol=1e-9 * delta)


def test_the_reference_action_compensates_a_sensor_delay():
    """A sensor delay of d samples puts the measured output, y(t - d h), on the law's reference, so the true output
    leads y_d by about d h y_d'; the shift delta = -d h y_d' takes that back. On a noise-free position episode with the
    delay alone, the true tracking error falls by far more than half (the unmodelled suite's ablation gives 46x for
    all effects, the delay alone dominating)."""
    env = EHSSTrackingEnv(task="position", action="reference", episode_seconds=1.0)
    d, h = 2, env.config.control_period
    sc = env.scenario_template.replace(reference=sine(1.0, 3.0), friction=(), t_end=1.0, unmodelled=Unmodelled(delay=d))
    D = env.config.action_bound
    rms = {}
    for comp in (False, True):
        env.reset(options={"scenario": sc})
        peek = env.unwrapped._lanes.peek
        done = False
        while not done:
            yd1 = peek[0, I_YD + 1]  # y_d' at the next sample [rad/s]
            a = np.clip(-d * h * yd1 / D, -1, 1) if comp else 0.0
            _, _, term, trunc, info = env.step(np.array([a], dtype=np.float32))
            done = term or trunc
        rms[comp] = info["metrics"]["trk_rmse"]
    assert rms[True] < 0.2 * rms[False], rms


def test_the_residual_reaches_the_plant_as_the_current_it_is():
    """With the rate mode the applied current is the base law's plus the residual state (the info's u_residual), the
    same as a current residual of that size."""
    env = EHSSTrackingEnv(action="rate", agent_period=1, episode_seconds=SHORT)
    env.reset(seed=4)
    for _ in range(30):
        _, _, _, _, info = env.step(np.array([1.0], dtype=np.float32))
        assert info["u_applied"] == pytest.approx(info["u_base"] + info["u_residual"], rel=1e-12, abs=1e-12)
        assert info["u_residual"] == env.unwrapped._lanes.info_ok[0, I_URES]


@pytest.mark.parametrize("part", ["reference", "schedule"])
def test_the_combined_mode_is_each_of_its_parts_with_the_other_at_zero(part):
    """reference-schedule with the schedule's entries at 0 is the reference mode, with the shift at 0 the schedule
    mode: rewards, infos and the law's slots byte for byte (random actions, the unmodelled effects and the class
    reward on)."""
    kw = {**RECIPE, "task": "position", "episode_seconds": 0.05}
    both = EHSSTrackingVectorEnv(2, action="reference-schedule", **kw)
    one = EHSSTrackingVectorEnv(2, action=part, **kw)
    both.reset(seed=3)
    one.reset(seed=3)
    rng = np.random.default_rng(0)
    cols = [0] if part == "reference" else [1, 2]
    for _ in range(60):
        a = rng.uniform(-1, 1, (2, len(cols))).astype(np.float32)
        full = np.zeros((2, 3), dtype=np.float32)
        full[:, cols] = a
        _, rb, tb, _, ib = both.step(full)
        _, ro, to, _, io = one.step(a)
        assert np.array_equal(rb, ro) and np.array_equal(tb, to)
        for key in ("u_applied", "u_base", "e", "s", "V"):
            assert np.array_equal(ib[key], io[key]), key
        for slot in (C_SHIFT, C_SMOOTH, C_LAYER_GAIN, C_SIGMA):
            assert np.array_equal(both._lanes.ctrl[:, slot], one._lanes.ctrl[:, slot])


@pytest.mark.parametrize("task", ["velocity", "position"])
def test_the_compensation_action_at_its_ends_is_the_loop_with_the_compensators_set_so(task):
    """a_0 = -1 switches the valve inverse off, a_1 = +1 doubles the reference delay: the episode's applied currents and
    errors are those of envs whose loop is set so (no inverse, twice the delay) with a zero current residual, byte for
    byte (the unmodelled effects on: a valve with a dead band and hysteresis, a sensor delay)."""
    kw = {**RECIPE, "task": task, "episode_seconds": 0.05}
    comp = EHSSTrackingVectorEnv(2, action="compensation", **kw, **COMPENSATORS)
    cases = {(-1.0, 0.0): {**COMPENSATORS, "inverse_threshold": 0.0, "inverse_hysteresis": 0.0},
             (0.0, 1.0): {**COMPENSATORS, "reference_delay": 2.0},
             (1.0, -1.0): {**COMPENSATORS, "reference_delay": 0.0, "inverse_threshold": 0.75,
                           "inverse_hysteresis": 4.5}}
    for (a0, a1), settings_ in cases.items():
        ref = EHSSTrackingVectorEnv(2, **kw, **settings_)
        comp.reset(seed=8)
        ref.reset(seed=8)
        a = np.tile(np.array([[a0, a1, 0.0, 0.0]], dtype=np.float32), (2, 1))
        for _ in range(40):
            _, _, tc, _, ic = comp.step(a)
            _, _, tr, _, ir = ref.step(np.zeros((2, 1), dtype=np.float32))
            assert np.array_equal(tc, tr)
            for key in ("u_applied", "u_base", "e", "s"):
                assert np.array_equal(ic[key], ir[key]), (a0, a1, key)
        c = comp._lanes.ctrl
        assert np.all(c[:, C_INV_THRESHOLD] == ref._lanes.ctrl[:, C_INV_THRESHOLD])
        assert np.all(c[:, C_INV_HYSTERESIS] == ref._lanes.ctrl[:, C_INV_HYSTERESIS])
        assert np.all(c[:, C_REF_DELAY] == ref._lanes.ctrl[:, C_REF_DELAY])


def test_the_compensation_actions_scaled_delay_stays_within_the_delay_line():
    env = EHSSTrackingEnv(task="position", action="compensation", reference_delay=6.0, episode_seconds=SHORT)
    env.reset(seed=0)
    env.step(np.array([0.0, 1.0, 0.0, 0.0], dtype=np.float32))
    assert env.unwrapped._lanes.ctrl[0, C_REF_DELAY] == MAX_DELAY


def test_bounds_default_per_task_and_are_settable():
    for task in ("velocity", "position"):
        for mode in ("rate", "filtered", "reference", "reference-schedule"):
            assert EnvConfig.from_kwargs({"task": task, "action": mode}).action_bound == \
                action_mode(mode).default_bound(task)
    assert EnvConfig.from_kwargs({"action": "rate", "action_bound": 0.5}).action_bound == 0.5
    assert EnvConfig.from_kwargs({}).action_bound is None


def test_validation_draws_the_unmodelled_effects_when_training_does():
    """ehss train's held-out validation is drawn as the training env draws its episodes, and the base law's rollout
    takes an action of the mode's size (zero)."""
    from ehss_gym.core.unmodelled import NONE
    from ehss_gym.evaluation.heldout import heldout_suite, run_episodes

    plain = heldout_suite({"task": "position"}, 3, 0)
    real = heldout_suite({"task": "position", "unmodelled_effects": True}, 3, 0)
    assert all(sc.unmodelled == NONE for sc in plain) and all(sc.unmodelled != NONE for sc in real)
    assert [sc.reference.description for sc in plain] == [sc.reference.description for sc in real]  # otherwise alike
    kw = {"task": "position", "action": "schedule", "episode_seconds": 0.05}
    scs = heldout_suite(kw, 2, 0, 0.05)
    keys = ("su_rmse", "tv_u_rate", "rms_u")  # (a 0.05 s episode is all start-up)
    got = [[m[k] for k in keys] for m in run_episodes(kw, scs)]
    assert got == [[m[k] for k in keys] for m in run_episodes({"task": "position", "episode_seconds": 0.05}, scs)]
