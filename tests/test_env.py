"""EHSSTracking-v0: registration, checkers, validation, seeding, robustness, vector env, scenarios."""

from __future__ import annotations

import math
import re
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import ehss_gym  # noqa: F401  (registers the env)
from ehss_gym import simulate, sine
from ehss_gym.core.layout import DIV_NAMES
from ehss_gym.core.scenarios import (
    DEFAULT_DISTRIBUTION,
    HELDOUT_SEED_BASE,
    TRAIN_SEED_LIMIT,
    describe,
    heldout_scenarios,
    paper_scenario,
    sample_scenario,
)
from ehss_gym.core.sim import LoopArrays
from ehss_gym.envs import DEFAULTS, OBS_BOUND, EHSSTrackingEnv, EHSSTrackingVectorEnv, EnvConfig, decode_observation
from ehss_gym.envs.env import HIST_COLUMNS
from ehss_gym.envs.lanes import STEP_INFO_KEYS, Lanes

DT = DEFAULTS.agent_period * DEFAULTS.control_period  # [s], one agent step at the defaults
SHORT = 200 * DT  # [s]
W = dict(DEFAULTS.reward_weights)
R_MIN = -(W["effort"] + W["rate"] + W["tv"] + W["divergence"])  # W["tv_u"] is 0 at the defaults
R_MAX = W["track"]


def test_make_registers_env_and_vector_entry_point():
    env = gym.make("EHSSTracking-v0", episode_seconds=SHORT)
    assert env.spec.id == "EHSSTracking-v0"
    assert isinstance(env.unwrapped, EHSSTrackingEnv)
    assert env.observation_space.shape == (15,) and env.action_space.shape == (1,)
    assert gym.make("EHSSTracking-v0", task="position").observation_space.shape == (17,)
    vec = gym.make_vec("EHSSTracking-v0", num_envs=2, vectorization_mode="vector_entry_point", episode_seconds=SHORT)
    assert isinstance(vec.unwrapped, EHSSTrackingVectorEnv)
    obs, _ = vec.reset(seed=0)
    assert obs.shape == (2, 15)


@pytest.mark.parametrize("task", ["velocity", "position"])
@pytest.mark.parametrize("mode", ["residual", "direct"])
def test_gymnasium_and_sb3_checkers_pass_without_warnings(task, mode):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        gym_check_env(gym.make("EHSSTracking-v0", task=task, mode=mode, episode_seconds=SHORT).unwrapped)
        sb3_check_env(EHSSTrackingEnv(task=task, mode=mode, episode_seconds=SHORT))


def test_checkers_pass_with_rgb_array_render_mode():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        env = gym.make("EHSSTracking-v0", render_mode="rgb_array", episode_seconds=SHORT)
        gym_check_env(env.unwrapped)
        sb3_check_env(EHSSTrackingEnv(render_mode="rgb_array", episode_seconds=SHORT))


def _mismatched_scenario():
    return EnvConfig.from_kwargs({}).template().replace(n=4)


BAD_KWARGS = [
    ({"foo": 1}, r"unknown keyword argument\(s\) \['foo'\]; valid: \['task', 'n'"),
    ({"task": "torque"}, r"task must be one of \['velocity', 'position'\]"),
    ({"n": 3}, r"n must be an even integer >= 2"),
    ({"fr": 0.0}, r"fr must be in \(0, inf\)"),
    ({"sigma": -1.0}, r"sigma must be in \(0, inf\)"),
    ({"smoothing": -1.0}, r"smoothing must be in \[0, inf\)"),
    ({"mode": "pure"}, r"mode must be one of \['residual', 'direct'\]"),
    ({"residual_scale": 0.0}, r"residual_scale must be in \(0, inf\)"),
    ({"agent_period": 0}, r"agent_period must be an integer >= 1"),
    ({"agent_period": 2.5}, r"agent_period must be an integer >= 1"),
    ({"control_period": 1.0}, r"control_period must be in \[1e-07, 0.01\]"),
    ({"substeps": 0}, r"substeps must be an integer >= 1"),
    ({"current_limit": -5.0}, r"current_limit must be in \(0, inf\)"),
    ({"estimator_hz": float("nan")}, r"estimator_hz must be a finite number"),
    ({"scenario": "nope"}, r"scenario must be one of \['random', 'paper'\] or an ehss_gym.Scenario"),
    ({"reward_weights": {"speed": 1.0}}, r"unknown reward_weights key\(s\) \['speed'\]; valid: \['track'"),
    ({"reward_weights": {"track": -1.0}}, r"reward_weights\['track'\] must be in \[0, inf\)"),
    ({"reward_weights": [1.0]}, r"reward_weights must be a dict with keys from \['track'"),
    ({"error_scale": 0.0}, r"error_scale must be in \(0, inf\)"),
    ({"episode_seconds": 1e-6}, re.escape(f"episode_seconds must be in [{DT:g}, inf)")),
    ({"render_mode": "human"}, r"render_mode must be None or one of \['rgb_array'\]"),
]


@pytest.mark.parametrize("kwargs,match", BAD_KWARGS, ids=[f"{next(iter(k))}{i}" for i, (k, _) in enumerate(BAD_KWARGS)])
def test_bad_keyword_arguments_raise_value_error_listing_what_is_valid(kwargs, match):
    with pytest.raises(ValueError, match=match):
        EHSSTrackingEnv(**kwargs)


def test_bad_keyword_through_gym_make_and_pinned_mismatch():
    with pytest.raises(ValueError, match="unknown keyword"):
        gym.make("EHSSTracking-v0", sigmaa=1.0)
    with pytest.raises(ValueError, match=r"differs from the env's controller settings in \['n'\]"):
        EHSSTrackingEnv(scenario=_mismatched_scenario())


def test_bad_reset_options_raise():
    env = EHSSTrackingEnv(episode_seconds=SHORT)
    with pytest.raises(ValueError, match=r"unknown reset option\(s\) \['level'\]; valid: \['scenario'\]"):
        env.reset(options={"level": 1})
    with pytest.raises(ValueError, match=r"scenario dict has unknown field\(s\) \['sigma'\]"):
        env.reset(options={"scenario": {"sigma": 3.0}})
    with pytest.raises(ValueError, match=r"options\['scenario'\] must be one of"):
        env.reset(options={"scenario": 7})
    with pytest.raises(ValueError, match=r"differs from the env's controller settings"):
        env.reset(options={"scenario": _mismatched_scenario()})
    with pytest.raises(ValueError, match="shorter than one agent step"):
        env.reset(options={"scenario": {"t_end": 0.5 * DT}})


def test_action_nan_raises_bad_shape_raises_out_of_range_is_clipped_and_counted():
    env = EHSSTrackingEnv(episode_seconds=SHORT)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="NaN"):
        env.step(np.array([np.nan], dtype=np.float32))
    with pytest.raises(ValueError, match="NaN"):
        env.step(float("nan"))
    with pytest.raises(ValueError, match=r"shape \(1,\)"):
        env.step(np.zeros(2, dtype=np.float32))
    _, _, _, _, info = env.step(np.array([0.5], dtype=np.float32))
    assert not info["clipped"] and info["n_clipped"] == 0
    assert info["u_residual"] == pytest.approx(0.5 * DEFAULTS.current_limit)
    _, _, _, _, info = env.step(np.array([7.0], dtype=np.float32))
    assert info["clipped"] and info["n_clipped"] == 1 and info["u_residual"] == DEFAULTS.current_limit
    _, _, _, _, info = env.step(np.array([-np.inf]))
    assert info["clipped"] and info["n_clipped"] == 2 and info["u_residual"] == -DEFAULTS.current_limit


def _episode(env, seed, actions):
    obs, info = env.reset(seed=seed)
    out = [obs]
    rews, flags, es = [], [], []
    for a in actions:
        obs, r, term, trunc, info = env.step(a)
        out.append(obs)
        rews.append(r)
        flags.append((term, trunc))
        es.append(info["e"])
        if term or trunc:
            break
    return np.array(out), np.array(rews), flags, np.array(es), info


def test_seeding_is_deterministic_over_a_full_episode():
    steps = 400
    actions = np.random.default_rng(5).uniform(-1, 1, (steps + 100, 1)).astype(np.float32)
    a = _episode(EHSSTrackingEnv(episode_seconds=steps * DT), 123, actions)
    b = _episode(EHSSTrackingEnv(episode_seconds=steps * DT), 123, actions)
    assert a[2][-1] == (False, True) and len(a[1]) == steps  # a full episode, ended by truncation
    for x, y in zip(a[:4], b[:4]):
        assert np.array_equal(x, y) if isinstance(x, np.ndarray) else x == y
    assert str(a[4]["metrics"]) == str(b[4]["metrics"])  # str: NaN recovery times compare equal
    c = _episode(EHSSTrackingEnv(episode_seconds=steps * DT), 124, actions)
    assert not np.array_equal(a[0], c[0])


@pytest.mark.parametrize("mode", ["residual", "direct"])
def test_ten_thousand_random_steps_over_random_scenarios_are_finite(mode):
    env = EHSSTrackingEnv(mode=mode, episode_seconds=1000 * DT)
    rng = np.random.default_rng(0)
    obs, _ = env.reset(seed=1)
    episodes, diverged = 1, 0
    for _ in range(10_000):
        obs, r, term, trunc, info = env.step(rng.uniform(-1.5, 1.5, 1).astype(np.float32))
        assert obs.dtype == np.float32 and np.all(np.isfinite(obs)) and np.all(np.abs(obs) <= OBS_BOUND)
        assert math.isfinite(r) and R_MIN <= r <= R_MAX
        assert all(math.isfinite(info[k]) for k in ("e", "s", "V", "u_base", "u_applied", "friction_torque"))
        if term or trunc:
            diverged += int(term)
            obs, _ = env.reset()
            episodes += 1
    assert episodes >= 10


def test_tv_reward_weight_is_an_l1_penalty_on_the_action_change():
    actions = np.array([[0.0], [0.6], [0.6], [-1.5], [0.2]], dtype=np.float32)  # -1.5 is clipped to -1
    runs = []
    for tv in (0.0, 0.8):
        env = EHSSTrackingEnv(episode_seconds=SHORT, reward_weights={"tv": tv})
        runs.append(_episode(env, 4, actions)[1])
    a = np.clip(actions[:, 0].astype(np.float64), -1.0, 1.0)
    da = np.abs(np.diff(np.concatenate([[0.0], a])))
    assert np.allclose(runs[0] - runs[1], 0.8 * da / 2, rtol=0, atol=1e-12)
    assert np.count_nonzero(runs[0] - runs[1]) == 3  # holding an action (0 at the start, the repeated 0.6) is free


def test_tv_u_reward_weight_charges_the_applied_current_total_variation():
    # Over a whole episode the tv_u term adds up to w * TV(u) / (agent_period * residual_scale), with TV(u) the
    # metric the evaluation scores (base-law switching included, not only the action's own changes).
    steps = round(SHORT / DT)
    actions = np.random.default_rng(2).uniform(-0.3, 0.3, (steps, 1)).astype(np.float32)
    w, scale = 0.7, 4.0
    runs = [_episode(EHSSTrackingEnv(episode_seconds=SHORT, residual_scale=scale, reward_weights={"tv_u": tv}), 6,
                     actions) for tv in (0.0, w)]
    assert runs[0][2][-1] == (False, True) and np.array_equal(runs[0][0], runs[1][0])  # same trajectory
    tv = runs[0][4]["metrics"]["tv_u"]
    assert tv > 0.0
    per_step = (runs[0][1] - runs[1][1]) * DEFAULTS.agent_period * scale / w  # each step's |du| sum [mA]
    assert np.all(per_step >= -1e-12)
    assert math.isclose(per_step.sum(), tv, rel_tol=1e-9)


def test_truncation_and_metrics_at_episode_end():
    env = EHSSTrackingEnv(episode_seconds=SHORT)
    env.reset(seed=3)
    n = 0
    while True:
        _, _, term, trunc, info = env.step(np.zeros(1, dtype=np.float32))
        n += 1
        if term or trunc:
            break
    assert (term, trunc) == (False, True) and n == round(SHORT / (DEFAULTS.agent_period * DEFAULTS.control_period))
    m = info["metrics"]
    assert m["steps"] == n * DEFAULTS.agent_period and not m["diverged"]
    assert {"rmse", "max_abs_e", "saturation", "tv_u", "recovery_on"} <= set(m)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(1, dtype=np.float32))


def test_divergence_terminates_with_finite_observation_and_penalty():
    # With the relief valves the plant cannot run away; what diverges here is one RK4 step of 50 us at a
    # 10 A valve opening (numerically unstable), which the env must catch and report.
    env = EHSSTrackingEnv(mode="direct", current_limit=None, residual_scale=1e4, episode_seconds=1.0,
                          control_period=5e-5)
    env.reset(seed=0, options={"scenario": "paper"})
    for _ in range(round(1.0 / (5e-5 * DEFAULTS.agent_period))):
        obs, r, term, trunc, info = env.step(np.ones(1, dtype=np.float32))
        if term or trunc:
            break
    assert term and not trunc and info["diverged"]
    assert info["divergence_reason"] in DIV_NAMES[1:] and info["t_diverged"] > 0
    assert info["metrics"]["diverged"]
    assert np.all(np.isfinite(obs)) and r <= -W["divergence"]
    assert all(math.isfinite(info[k]) for k in ("e", "s", "u_applied"))


def test_zero_residual_episode_matches_the_core_simulator():
    env = EHSSTrackingEnv(episode_seconds=SHORT)
    phys = {"reference": sine(1.0, 2.0), "friction": ((1.8, 0.2, 0.3),), "t_end": 3000 * DT}  # whole agent steps
    env.reset(options={"scenario": phys})
    while True:
        _, _, term, trunc, info = env.step(np.zeros(1, dtype=np.float32))
        if term or trunc:
            break
    ref = simulate(env.scenario).metrics()
    for key in ("rmse", "rmse_nominal", "iae", "max_abs_e", "max_abs_e_friction", "tv_u", "peak_u", "saturation",
                "v_decrease", "steps"):
        assert info["metrics"][key] == ref[key], key


def test_observation_is_the_controllers_next_sample():
    # agent_period 1: the next step's only control sample is the one the observation previewed.
    env = EHSSTrackingEnv(agent_period=1, episode_seconds=SHORT)
    obs, _ = env.reset(seed=2)
    for _ in range(50):
        e_obs = decode_observation(obs, env.observation_layout)["e"]
        obs, _, _, _, info = env.step(np.zeros(1, dtype=np.float32))
        assert e_obs == pytest.approx(info["e"], rel=1e-6, abs=1e-12)


def test_render_rgb_array_dashboard():
    env = EHSSTrackingEnv(render_mode="rgb_array", episode_seconds=SHORT)
    env.reset(seed=0)
    for _ in range(20):
        env.step(np.zeros(1, dtype=np.float32))
    img = env.render()
    assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3 and min(img.shape[:2]) > 100
    assert len(np.unique(img.reshape(-1, 3), axis=0)) > 10
    plain = EHSSTrackingEnv(episode_seconds=SHORT)
    plain.reset(seed=0)
    with pytest.warns(UserWarning, match="render_mode"):
        assert plain.render() is None


def _run_vector_against_singles(kwargs, n_envs, n_steps, low, high, seed, threads=1):
    venv = EHSSTrackingVectorEnv(n_envs, threads=threads, **kwargs)
    assert venv._lanes.n_chunks == min(threads, n_envs)
    envs = [EHSSTrackingEnv(**kwargs) for _ in range(n_envs)]
    obs, _ = venv.reset(seed=seed)
    assert np.array_equal(obs, np.stack([e.reset(seed=seed + i)[0] for i, e in enumerate(envs)]))
    rng = np.random.default_rng(seed)
    pending = [False] * n_envs
    ends = diverged = 0
    phases = set()
    for _ in range(n_steps):
        A = rng.uniform(low, high, (n_envs, 1)).astype(np.float32)
        o, r, te, tr, _ = venv.step(A)
        phases.add(tuple(venv._lanes.k[:n_envs]))
        for i, e in enumerate(envs):
            if pending[i]:
                so, _ = e.reset()
                sr, ste, s_tr = 0.0, False, False
                pending[i] = False
            else:
                so, sr, ste, s_tr, _ = e.step(A[i])
                pending[i] = ste or s_tr
                ends += int(ste or s_tr)
                diverged += int(ste)
            assert np.array_equal(so, o[i]) and sr == r[i] and ste == te[i] and s_tr == tr[i]
    return ends, diverged, phases


@pytest.mark.parametrize("threads", [1, 2])
def test_vector_env_equals_single_envs_with_autoreset(threads):
    ends, _, _ = _run_vector_against_singles({"episode_seconds": 40 * DT}, 3, 100, -1.2, 1.2, 10, threads)
    assert ends >= 3 * 2


@pytest.mark.parametrize("threads", [1, 2])
def test_vector_env_equals_single_envs_when_lanes_fall_out_of_phase(threads):
    # Huge direct currents diverge at action-dependent times, so lanes restart out of phase.
    # (50 us: an RK4 step that is unstable at these currents, see the divergence test above)
    kw = {"mode": "direct", "current_limit": None, "residual_scale": 1e5, "episode_seconds": 0.05,
          "control_period": 5e-5}
    ends, diverged, phases = _run_vector_against_singles(kw, 4, 150, 0.0, 1.0, 20, threads)
    assert diverged >= 2
    assert any(len(set(p)) > 1 for p in phases)  # some steps advanced lanes at different step indices


def test_vector_env_validation_and_nan():
    with pytest.raises(ValueError, match="num_envs must be an integer >= 1"):
        EHSSTrackingVectorEnv(0)
    with pytest.raises(ValueError, match="render_mode must be None"):
        EHSSTrackingVectorEnv(2, render_mode="rgb_array")
    with pytest.raises(ValueError, match="chunk must be an integer >= 1"):
        EHSSTrackingVectorEnv(2, chunk=0)
    with pytest.raises(ValueError, match="threads must be an integer >= 1"):
        EHSSTrackingVectorEnv(2, threads=0)
    with pytest.raises(ValueError, match="unknown keyword"):
        EHSSTrackingVectorEnv(2, foo=1)
    venv = EHSSTrackingVectorEnv(2, episode_seconds=SHORT)
    with pytest.raises(ValueError, match="list of 2"):
        venv.reset(seed=[1, 2, 3])
    venv.reset(seed=0)
    with pytest.raises(ValueError, match="NaN"):
        venv.step(np.array([[0.0], [np.nan]], dtype=np.float32))
    obs, r, te, tr, infos = venv.step(np.array([[0.0], [3.0]], dtype=np.float32))
    assert obs.shape == (2, 15) and r.shape == (2,) and infos["clipped"].tolist() == [False, True]
    assert infos["u_residual"][1] == DEFAULTS.current_limit and infos["_e"].all()
    # every step key, each followed by its mask (all sub-envs have it), in the order of the single env's info
    env = EHSSTrackingEnv(episode_seconds=SHORT)
    env.reset(seed=0)
    single = env.step(np.zeros(1, dtype=np.float32))[4]
    assert list(single) == list(STEP_INFO_KEYS)
    assert list(infos) == [k for key in STEP_INFO_KEYS for k in (key, "_" + key)]
    assert all(infos["_" + key].dtype == np.bool_ and infos["_" + key].all() for key in STEP_INFO_KEYS)


# --- scenarios -------------------------------------------------------------------------------------


def test_reset_reports_random_draw_and_paper_scenario():
    env = EHSSTrackingEnv()
    _, info = env.reset(seed=4)
    assert info["scenario_name"] == "random" and 0 <= info["scenario_seed"] < TRAIN_SEED_LIMIT
    assert info["scenario"]["t_end"] == DEFAULT_DISTRIBUTION.episode_seconds
    again = sample_scenario(info["scenario_seed"], env.scenario_template)
    assert describe(again) == info["scenario"]
    _, info = env.reset(options={"scenario": "paper"})
    assert info["scenario_name"] == "paper" and info["scenario"]["t_end"] == 20.0
    assert info["scenario"]["friction"] == [(1.8, 8.0, 10.0)] and info["scenario"]["noise_std"] == (0.0,) * 4
    pinned = env.scenario_template.replace(friction=((1.0, 0.01, 0.02),), t_end=0.05)
    _, info = env.reset(options={"scenario": pinned})
    assert info["scenario_name"] == "pinned" and env.scenario is pinned


def test_random_distribution_covers_its_ranges():
    tmpl = EnvConfig.from_kwargs({}).template()
    scs = [sample_scenario(s, tmpl) for s in range(300)]
    assert {s.reference.family for s in scs} == {"sine", "step", "chirp", "multisine"}
    assert {len(s.friction) for s in scs} == {0, 1, 2, 3}
    amps = [ev[0] for s in scs for ev in s.friction]
    assert 0.0 <= min(amps) and max(amps) <= 3.6 and max(amps) > 3.0
    for s in scs:
        d = describe(s)
        assert all(0.8 <= v <= 1.2 for v in d["plant_scaling"].values()) and d["model_mismatch"]
        assert s.model == ehss_gym.PlantParams() and s.t_end == 2.0
    noisy = [s for s in scs if any(s.noise_std)]
    assert 0.3 * len(scs) < len(noisy) < 0.7 * len(scs)


def test_heldout_scenarios_are_deterministic_and_disjoint_from_training_seeds():
    tmpl = EnvConfig.from_kwargs({}).template()
    a = heldout_scenarios(5, tmpl)
    b = heldout_scenarios(5, tmpl)
    assert [describe(x) for x in a] == [describe(y) for y in b]
    assert len({str(describe(x)) for x in a}) == 5
    assert describe(a[0]) == describe(sample_scenario(HELDOUT_SEED_BASE, tmpl))
    assert HELDOUT_SEED_BASE >= TRAIN_SEED_LIMIT
    assert describe(heldout_scenarios(1, tmpl, start=3)[0]) == describe(a[3])
    with pytest.raises(ValueError, match="count must be an integer >= 1"):
        heldout_scenarios(0, tmpl)
    with pytest.raises(ValueError, match="scenario_seed must be an integer >= 0"):
        sample_scenario(-1, tmpl)


def test_lane_rows_match_the_core_loop_arrays():
    cfg = EnvConfig.from_kwargs({})
    sc = sample_scenario(11, cfg.template())
    lanes = Lanes(cfg, 1)
    lanes.load(0, sc)
    ref = LoopArrays.build([sc])
    for name in ("z0", "plant", "model", "ctrl", "ref", "filt"):
        ours = {"z0": lanes.z}.get(name, getattr(lanes, name, None))
        assert np.array_equal(ours, getattr(ref, name)), name
    E = len(sc.friction)
    assert np.array_equal(lanes.events[0, :E], ref.events[0, :E])


def test_default_base_law_is_not_a_relay_on_the_paper_run():
    # Measured under the defaults: saturation 0.00028 (the start-up transient), rmse 5.4e-3 rad/s.
    m = simulate(paper_scenario(EnvConfig.from_kwargs({}).template())).metrics()
    assert not m["diverged"] and m["saturation"] < 0.01


def test_env_defaults_are_the_reproduction_studys_recommendation():
    """ehss_gym.envs.env.DEFAULTS restate reports/paper/recommended_defaults.json (made by `ehss reproduce`) in what
    that study chose and no later study replaced: the period, substeps, limit, the SVF's cutoff and the digital
    filters' scheme. The estimator and the law are the noise study's (tests/test_noise.py): where the task's
    estimator is the SVF it runs in the reproduction study's scheme, and otherwise the reference model does. n,
    f_r, the smoothing and sigma are the baselines' tuning (tests/test_baselines.py)."""
    import json
    import pathlib

    from ehss_gym.core.filters import SCHEMES
    from ehss_gym.envs import DEFAULTS

    rec = json.loads((pathlib.Path(__file__).parents[1] / "reports/paper/recommended_defaults.json").read_text())
    assert not rec["quick_mode"]
    assert DEFAULTS.control_period == rec["control_period_s"] and DEFAULTS.substeps == rec["substeps"]
    assert DEFAULTS.current_limit == rec["current_limit_mA"]
    for task in ("velocity", "position"):
        td = getattr(DEFAULTS, task)
        assert td.estimator_hz == rec["estimator_hz"][task], task
        assert td.estimator == rec["estimator"] or td.estimator not in SCHEMES, task
        sc = EnvConfig.from_kwargs({"task": task}).template()
        assert sc.estimator == td.estimator


def test_constructor_signature_is_the_config_record():
    """help(EHSSTrackingEnv) lists every setting, keyword-only, with the defaults of DEFAULTS (None: per task)."""
    import inspect

    from ehss_gym.envs.config import TASK_DEPENDENT

    params = inspect.signature(EHSSTrackingEnv.__init__).parameters
    named = {k: p for k, p in params.items() if k not in ("self", "unknown")}
    assert set(named) == set(EnvConfig.KEYS) | {"render_mode"}
    assert all(p.kind is inspect.Parameter.KEYWORD_ONLY for p in named.values())
    for key in ("mode", "n", "control_period", "substeps", "agent_period", "pressure_domain", "scenario"):
        assert named[key].default == getattr(DEFAULTS, key), key
    # the current limit defaults to the plant's rated current: Table I's is the env's documented 10 mA
    assert named["current_limit"].default == "rated" and named["plant"].default is None
    assert EnvConfig.from_kwargs({}).current_limit == DEFAULTS.current_limit == EnvConfig.from_kwargs(
        {"plant": "compact140", "current_limit": DEFAULTS.current_limit}).current_limit
    for key in TASK_DEPENDENT:
        assert named[key].default is None, key
    assert named["task"].default == "velocity"
    doc = inspect.getdoc(EHSSTrackingEnv)
    assert all(f"{k}:" in doc for k in EnvConfig.KEYS)  # each argument is documented in the class docstring
    # the typed arguments reach the config, None picks the task's default, unknown names are still refused
    env = EHSSTrackingEnv(task="position", fr=None, sigma=3e5)
    assert env.config.fr == DEFAULTS.position.fr and env.config.sigma == 3e5
    with pytest.raises(ValueError, match=r"unknown keyword argument\(s\) \['bogus'\]"):
        EHSSTrackingEnv(bogus=1)


def test_vector_env_equals_single_envs_out_of_phase_with_analog_filters():
    """Lanes out of phase with the analog estimator: the plant's integrator advances each lane's continuous filters
    with the reference at that lane's own time, so every sub-env still equals its single env."""
    kw = {"mode": "direct", "current_limit": None, "residual_scale": 1e5, "episode_seconds": 0.05,
          "control_period": 5e-5, "estimator": "analog"}
    _, diverged, phases = _run_vector_against_singles(kw, 4, 150, 0.0, 1.0, 20)
    assert diverged >= 2
    assert any(len(set(p)) > 1 for p in phases)


def test_a_steps_current_range_is_that_of_its_control_periods():
    """The step's applied-current range (the dashboard's band) against the currents of the same periods run one per
    step: an env of agent_period 1 with the same seed and zero residuals runs the same periods. The extremes fall on
    every period of the step, the first included, so a range that skipped or mis-seeded one would differ."""
    envs = [gym.make("EHSSTracking-v0", render_mode="rgb_array", agent_period=p).unwrapped for p in (5, 1)]
    for env, n in zip(envs, (60, 300)):
        env.reset(seed=3)
        for _ in range(n):
            env.step(np.zeros(1, np.float32))
    col = {name: i for i, name in enumerate(HIST_COLUMNS)}
    steps, periods = (np.array(env._hist)[1:] for env in envs)  # row 0 is the reset's
    u = periods[:, col["u_applied"]].reshape(60, 5)
    assert np.array_equal(steps[:, col["u_min"]], u.min(axis=1))
    assert np.array_equal(steps[:, col["u_max"]], u.max(axis=1))
    assert set(u.argmin(axis=1)) == set(range(5)) and set(u.argmax(axis=1)) == set(range(5))
