"""The agents: residual PPO starts exactly at the base law; hyperparameters are validated and documented."""

import numpy as np
import pytest
import torch
from ehss_gym.agents.specs import AGENTS, AgentSpec, env_kwargs_for, get_spec, initial_mean_abs, make_agent
from ehss_gym.train.loop import make_env

SHORT = {"episode_seconds": 0.05}  # 100 agent steps


@pytest.fixture(scope="module")
def residual():
    torch.set_num_threads(1)
    spec = get_spec("residual-ppo", n_envs=2, n_steps=64, batch_size=64)
    venv = make_env({**env_kwargs_for(spec, "velocity", 2), **SHORT}, spec.n_envs, spec.gamma, spec.norm_reward)
    return spec, venv, make_agent(spec, venv, seed=0)


def test_residual_mean_is_exactly_zero_and_noise_as_specified(residual):
    spec, venv, model = residual
    obs = np.stack([venv.reset() for _ in range(3)]).reshape(-1, venv.observation_space.shape[0])
    rng = np.random.default_rng(0)
    obs = np.concatenate([obs, rng.normal(size=(200, obs.shape[1])).astype(np.float32) * 3])
    assert initial_mean_abs(model, obs) == 0.0
    assert np.allclose(model.policy.log_std.detach().numpy(), spec.log_std_init)
    assert np.all(model.predict(obs, deterministic=True)[0] == 0.0)


def test_untrained_residual_policy_is_the_base_law(residual):
    """Same episode, deterministic untrained policy vs the zero residual: identical metrics."""
    from ehss_gym.evaluation.heldout import heldout_suite, run_episodes, sb3_act_fn

    spec, venv, model = residual
    kw = env_kwargs_for(spec, "velocity", 2)
    scs = heldout_suite(kw, 2, start=123, episode_seconds=0.05)
    got = run_episodes(kw, scs, sb3_act_fn(model, venv))
    base = run_episodes(kw, scs, None)
    for g, b in zip(got, base):
        for k in ("rmse", "max_abs_e", "tv_u_rate", "saturation"):
            assert g[k] == b[k]
    # and a non-zero residual does change the loop (so the comparison above can fail)
    push = run_episodes(kw, scs, lambda o: np.full((len(o), 1), 0.5, dtype=np.float32))
    assert push[0]["rmse"] != base[0]["rmse"]


def test_learning_moves_the_mean(residual):
    spec, venv, model = residual
    model.learn(256)  # two updates; with the linear schedule the first one has half the initial step size
    obs = venv.normalize_obs(np.stack([venv.reset()[0] for _ in range(2)]))
    assert initial_mean_abs(model, obs) > 0.0


def test_pure_ppo_is_direct_mode_with_standard_init():
    spec = get_spec("ppo", n_envs=1, n_steps=64, batch_size=64)
    assert spec.mode == "direct" and not spec.zero_init_action
    venv = make_env({**env_kwargs_for(spec, "velocity", 2), **SHORT}, 1, spec.gamma, spec.norm_reward)
    model = make_agent(spec, venv, seed=0)
    assert venv.get_attr("config")[0].mode == "direct"
    obs = venv.reset()
    assert initial_mean_abs(model, obs) > 0.0  # orthogonal init with gain 0.01, not zeroed


def test_bad_agent_input():
    with pytest.raises(ValueError, match=r"agent must be one of \['ppo', 'residual-ppo'\]"):
        get_spec("sac")
    with pytest.raises(ValueError, match=r"unknown or fixed agent hyperparameter\(s\) \['mode'\]"):
        get_spec("residual-ppo", mode="direct")
    with pytest.raises(ValueError, match=r"gamma must be a number in \(0, 1\]"):
        get_spec("residual-ppo", gamma=1.5)
    with pytest.raises(ValueError, match="n_steps must be an integer >= 1"):
        get_spec("ppo", n_steps=0)
    with pytest.raises(ValueError, match="env_kwargs must be a dict of EHSSTracking-v0 keyword arguments other"):
        get_spec("ppo", env_kwargs={"task": "position"})


def test_env_kwargs_override_merges():
    spec = get_spec("residual-ppo", env_kwargs={"agent_period": 20})
    assert spec.env_kwargs == {**AGENTS["residual-ppo"].env_kwargs, "agent_period": 20}
    assert env_kwargs_for(spec, "position", 4) == {"task": "position", "n": 4, "mode": "residual",
                                                   **spec.env_kwargs}


def test_every_hyperparameter_is_documented():
    doc = AgentSpec.__doc__
    for name in AgentSpec.__dataclass_fields__:
        assert f"\n        {name}:" in doc, name
