"""Scripted policies: SB3 interface, the CLF law in both modes, PID tuning, residual authority."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.monitor import Monitor

import ehss_gym  # noqa: F401  (registers the env)
from ehss_gym import sine
from ehss_gym.controllers import (
    PID_GAINS,
    PID_RELAY,
    PID_RELAY_GAINS,
    CLFPolicy,
    FrictionFeedforwardPolicy,
    PIDPolicy,
    relay_experiment,
    tune_pid,
)
from ehss_gym.envs import DEFAULTS, EHSSTrackingEnv, EnvConfig

SHORT = 0.05
FRICTION = ((1.8, 1.0, 1.5),)
PAPER_LIKE = {"reference": sine(1.0, 2.0), "friction": FRICTION, "t_end": 2.0}


def _run(env, policy, physical):
    obs, _ = env.reset(options={"scenario": physical})
    state, start = None, True
    while True:
        action, state = policy.predict(obs, state, np.array([start]))
        start = False
        obs, _, term, trunc, info = env.step(action)
        if term or trunc:
            return info["metrics"]


@pytest.mark.parametrize("mode", ["residual", "direct"])
def test_evaluate_policy_accepts_every_scripted_policy(mode):
    env = Monitor(gym.make("EHSSTracking-v0", mode=mode, episode_seconds=SHORT))
    env.reset(seed=3)  # evaluate_policy's resets continue this generator: the same scenarios on every run
    policies = [CLFPolicy(env), PIDPolicy(env)]
    if mode == "residual":
        policies.append(FrictionFeedforwardPolicy(env, ((1.0, 0.01, 0.03),)))
    for policy in policies:
        mean, std = evaluate_policy(policy, env, n_eval_episodes=2, deterministic=True, warn=False)
        assert math.isfinite(mean) and math.isfinite(std) and mean > 0.0
    venv = make_vec_env("EHSSTracking-v0", n_envs=2, seed=4, env_kwargs={"mode": mode, "episode_seconds": SHORT})
    for policy in policies:
        mean, _ = evaluate_policy(policy, venv, n_eval_episodes=2, deterministic=True, warn=False)
        assert math.isfinite(mean)


def test_predict_shapes_and_pid_state():
    env = EHSSTrackingEnv(mode="direct", episode_seconds=SHORT)
    obs, _ = env.reset(seed=0)
    pid = PIDPolicy(env)
    a, state = pid.predict(obs)
    assert a.shape == (1,) and a.dtype == np.float32 and state.shape == (1, 1)
    batch = np.stack([obs, obs, obs])
    a, state = pid.predict(batch, None, np.ones(3, dtype=bool))
    assert a.shape == (3, 1) and state.shape == (3, 1)
    # integral state: accumulates, is clamped (anti-windup) and resets at episode start
    big = batch.copy()
    big[:, 0] = 9.0  # e = expm1(9) * error_scale ~ 81 rad/s
    s = state
    for _ in range(10_000):
        _, s = pid.predict(big, s, np.zeros(3, dtype=bool))
    assert np.all(np.abs(s) <= pid.i_limit) and np.all(np.abs(s) > 0.5 * pid.i_limit)
    _, s2 = pid.predict(big, s, np.array([True, False, False]))
    assert abs(s2[0, 0]) < abs(s2[1, 0])
    a, _ = CLFPolicy(EHSSTrackingEnv(episode_seconds=SHORT)).predict(batch)
    assert a.shape == (3, 1) and np.all(a == 0.0)


def test_bad_policy_arguments_raise():
    env = EHSSTrackingEnv(mode="direct", episode_seconds=SHORT)
    with pytest.raises(ValueError, match=r"gains must be three finite numbers >= 0"):
        PIDPolicy(env, gains=(1.0, -1.0, 0.0))
    with pytest.raises(ValueError, match=r"gains must be three finite numbers >= 0"):
        PIDPolicy(env, gains=(1.0, 2.0))
    with pytest.raises(ValueError, match="needs mode='residual'"):
        FrictionFeedforwardPolicy(env, FRICTION)
    with pytest.raises(ValueError, match="cannot find an EHSSTracking-v0 config"):
        CLFPolicy(gym.make("Pendulum-v1"))


def test_direct_mode_clf_policy_is_the_sontag_law():
    # Acting every control period, the direct-mode CLF policy applies the Sontag current the residual
    # env applies itself; they differ only by the float32 observation (relative ~1e-7).
    phys = {"reference": sine(1.0, 2.0), "friction": ((1.8, 0.2, 0.3),), "t_end": 0.5}
    res = EHSSTrackingEnv(agent_period=1)
    m_res = _run(res, CLFPolicy(res), phys)
    direct = EHSSTrackingEnv(mode="direct", agent_period=1)
    m_dir = _run(direct, CLFPolicy(direct), phys)
    for key in ("rmse", "max_abs_e_friction", "tv_u", "iae"):
        assert m_dir[key] == pytest.approx(m_res[key], rel=1e-5), key


@pytest.mark.parametrize("n", [2, 4, 6])
@pytest.mark.parametrize("mode", ["residual", "direct"])
def test_clf_policy_runs_for_every_n(n, mode):
    env = EHSSTrackingEnv(n=n, mode=mode)
    m = _run(env, CLFPolicy(env), {"reference": sine(1.0, 2.0), "friction": ((1.8, 0.2, 0.3),), "t_end": 0.4})
    assert not m["diverged"] and m["rmse"] < 0.2


def test_residual_channel_has_authority_under_the_defaults():
    """A friction feed-forward that knows the event lowers max |e| in the friction window.

    Measured (velocity task, defaults): zero residual 0.0376 rad/s, feed-forward 0.0160 rad/s.
    """
    env = EHSSTrackingEnv()
    base = _run(env, CLFPolicy(env), PAPER_LIKE)
    ff = _run(env, FrictionFeedforwardPolicy(env, FRICTION), PAPER_LIKE)
    assert ff["max_abs_e_friction"] < 0.8 * base["max_abs_e_friction"]
    # The authority comes from acting before the edge: the same doublet started at the edge barely helps
    # (the base law is already at the current limit right after the switch-on).
    late = _run(env, FrictionFeedforwardPolicy(env, FRICTION, start_at_edge=True), PAPER_LIKE)
    assert late["max_abs_e_friction"] > 0.9 * base["max_abs_e_friction"]
    assert ff["rmse"] <= base["rmse"]
    assert base["saturation"] < 0.01  # the base law is not a relay under the defaults


def test_relay_experiment_reproduces_the_recorded_ultimate_point():
    cfg = EnvConfig.from_kwargs({"task": "velocity", "mode": "direct"})
    Ku, Tu, a = relay_experiment(cfg)
    assert (Ku, Tu) == pytest.approx(PID_RELAY[("velocity", "direct")], rel=1e-9)
    assert a > 0 and Tu > 10 * cfg.agent_dt


def test_stored_pid_gains_are_used_for_default_settings():
    for (task, mode), gains in PID_GAINS.items():
        pid = PIDPolicy(EnvConfig.from_kwargs({"task": task, "mode": mode}))
        assert (pid.kp, pid.ki, pid.kd) == gains
    assert DEFAULTS.agent_period == 5  # PID_GAINS were tuned at this agent period


@pytest.mark.slow
@pytest.mark.parametrize("key", sorted(PID_RELAY_GAINS), ids=lambda k: "-".join(k))
def test_tuning_procedure_reproduces_stored_pid_gains(key):
    task, mode = key
    out = tune_pid(EnvConfig.from_kwargs({"task": task, "mode": mode}))
    assert out["gains"] == pytest.approx(PID_RELAY_GAINS[key], rel=1e-9)
    assert (out["Ku"], out["Tu"]) == pytest.approx(PID_RELAY[key], rel=1e-9)
