"""The agents: residual PPO starts exactly at the base law; hyperparameters are validated and documented; rl-zoo3's
files are generated from the specs and build the same agent."""

import copy
import importlib
import os

import numpy as np
import pytest
import torch
import yaml
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import VecNormalize

from ehss_gym.agents.factory import AgentMlpPolicy, initial_mean_abs, make_agent
from ehss_gym.agents.hyperparams import ppo as zoo_module
from ehss_gym.agents.specs import AGENTS, AgentSpec, env_kwargs_for, get_spec
from ehss_gym.train import zoo
from ehss_gym.train.loop import make_env

pytestmark = pytest.mark.xdist_group("agents")  # one worker computes the residual agent (a module fixture) once

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
    k = venv.action_space.shape[0]  # the recipe's action mode's size
    push = run_episodes(kw, scs, lambda o: np.full((len(o), k), 0.5, dtype=np.float32))
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


def test_policy_class_is_mlppolicy_with_a_zeroed_action_net():
    """AgentMlpPolicy draws the same numbers as SB3's MlpPolicy: every parameter equal for the same seed, the action
    net zero where asked (the recipe of the shipped runs: MlpPolicy, then the action net zeroed)."""
    spec = get_spec("residual-ppo", n_envs=1, n_steps=64, batch_size=64)
    venv = make_env({**env_kwargs_for(spec, "velocity", 2), **SHORT}, 1, spec.gamma, spec.norm_reward)
    ours = make_agent(spec, venv, seed=4).policy.state_dict()
    kw = {"net_arch": {"pi": [64, 64], "vf": [64, 64]}, "activation_fn": torch.nn.Tanh,
          "log_std_init": spec.log_std_init}
    sb3 = PPO("MlpPolicy", venv, seed=4, device="cpu", policy_kwargs=kw).policy.state_dict()
    assert sorted(ours) == sorted(sb3)
    for k in ours:
        want = torch.zeros_like(sb3[k]) if k.startswith("action_net.") else sb3[k]
        assert torch.equal(ours[k], want), k


def test_policy_class_round_trips_through_sb3_save(residual, tmp_path):
    _, venv, model = residual
    model.save(tmp_path / "m.zip")
    loaded = PPO.load(tmp_path / "m.zip", device="cpu")
    assert isinstance(loaded.policy, AgentMlpPolicy) and loaded.policy.zero_init_action
    a, b = model.policy.state_dict(), loaded.policy.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)  # the zeroing at construction does not overwrite loaded weights


def test_bad_agent_input():
    with pytest.raises(ValueError,
                       match=r"agent must be one of \['ppo', 'residual-ppo', 'residual-ppo-eso', 'residual-sac'\]"):
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


def test_the_observers_residual_acts_in_eso_n2s_loop_on_the_velocity_task_only():
    """residual-ppo-eso is the residual recipe as it is on the loop of the scripted eso-n2 (the same controller
    settings, defaults resolved), and refuses the position task, where the compensator rule chose no observer."""
    from ehss_gym.controllers import parse_scripted
    from ehss_gym.evaluation.specs import controller_settings

    spec = AGENTS["residual-ppo-eso"]
    assert spec.tasks == ("velocity",) and spec.as_dict()["tasks"] == ["velocity"]
    assert "tasks" not in AGENTS["residual-ppo"].as_dict()  # an agent of both tasks keeps its earlier record
    assert {k: v for k, v in spec.as_dict().items() if k not in ("name", "env_kwargs", "tasks")} == {
        k: v for k, v in AGENTS["residual-ppo"].as_dict().items() if k not in ("name", "env_kwargs")}
    kw = env_kwargs_for(spec, "velocity", 2)
    assert controller_settings(kw, "velocity") == controller_settings(parse_scripted("eso-n2", "velocity"), "velocity")
    assert controller_settings(kw, "velocity") != controller_settings({"n": 2}, "velocity")
    with pytest.raises(ValueError, match=r"agent 'residual-ppo-eso' trains on the task\(s\) \['velocity'\], got "
                                         r"task 'position'"):
        env_kwargs_for(spec, "position", 2)
    assert AgentSpec(**{**spec.as_dict(), "net_arch": (64, 64)}).tasks == ("velocity",)  # from a run's record
    with pytest.raises(ValueError, match=r"tasks must be a non-empty tuple of tasks of \['velocity', 'position'\]"):
        get_spec("residual-ppo", tasks=("torque",))


def test_every_hyperparameter_is_documented():
    doc = AgentSpec.__doc__
    for name in AgentSpec.__dataclass_fields__:
        assert f"\n        {name}:" in doc, name


# --- rl-zoo3 -------------------------------------------------------------------------------------------


def test_zoo_files_are_generated_from_the_specs():
    """agents/hyperparams/ppo.yml and ppo.py are what python -m ehss_gym.train.zoo writes from AGENTS (rerun it
    after changing a spec); both hold the same hyperparameters."""
    for path, text in zoo.files().items():
        with open(path, encoding="utf-8") as f:
            assert f.read() == text, f"{path} is stale: run python -m ehss_gym.train.zoo"
    with open(os.path.join(zoo.HYPERPARAMS_DIR, "ppo.yml"), encoding="utf-8") as f:
        assert yaml.safe_load(f) == zoo_module.hyperparams == zoo.hyperparams()
    assert zoo.main(["--check"]) == 0


def _zoo_model(hyperparams: dict, seed: int):
    """The PPO model rl-zoo3's ExperimentManager builds from a hyperparameter entry (its preprocessing, re-done)."""
    hp = copy.deepcopy(hyperparams)
    env_kwargs, n_envs = hp.pop("env_kwargs"), hp.pop("n_envs")
    hp.pop("n_timesteps")
    normalize = {**eval(hp.pop("normalize")), "gamma": hp["gamma"]}  # rl-zoo3 evaluates the string, adds gamma
    hp["policy_kwargs"] = eval(hp["policy_kwargs"], {"nn": torch.nn})
    module, _, name = hp.pop("policy").rpartition(".")
    schedule, _, initial = hp.pop("learning_rate").partition("_")
    assert schedule == "lin"
    venv = make_env(env_kwargs, n_envs, normalize["gamma"], normalize["norm_reward"], native=False)
    assert normalize == {"norm_obs": True, "norm_reward": venv.norm_reward, "clip_obs": venv.clip_obs,
                         "gamma": venv.gamma}
    model = PPO(getattr(importlib.import_module(module), name), venv, seed=seed, device="cpu",
                learning_rate=lambda p: p * float(initial), **hp)
    return model, env_kwargs


def test_zoo_hyperparameters_build_the_agent_of_ehss_train():
    spec = get_spec("residual-ppo")
    zoo_model, env_kwargs = _zoo_model(zoo_module.hyperparams["EHSSTracking-v0"], seed=0)
    assert env_kwargs == env_kwargs_for(spec, "velocity", 2)
    ours = make_agent(spec, make_env(env_kwargs, spec.n_envs, spec.gamma, spec.norm_reward), seed=0)
    for k in ("n_steps", "batch_size", "n_epochs", "gamma", "gae_lambda", "ent_coef", "vf_coef", "max_grad_norm",
              "target_kl", "n_envs", "policy_class", "policy_kwargs"):
        assert getattr(zoo_model, k) == getattr(ours, k), k
    for p in (1.0, 0.37, 0.0):
        assert zoo_model.lr_schedule(p) == ours.lr_schedule(p) and zoo_model.clip_range(p) == ours.clip_range(p)
    a, b = zoo_model.policy.state_dict(), ours.policy.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert isinstance(zoo_model.get_env(), VecNormalize)


def test_rl_zoo3_reads_the_module_as_generated():
    """With rl-zoo3 installed: its own ExperimentManager preprocessing gives the hyperparameters above."""
    exp_manager = pytest.importorskip("rl_zoo3.exp_manager")
    em = exp_manager.ExperimentManager.__new__(exp_manager.ExperimentManager)
    em.config, em.algo, em.custom_hyperparams, em.storage = "ehss_gym.agents.hyperparams.ppo", "ppo", None, None
    em.env_name = exp_manager.EnvironmentName("EHSSTracking-v0")
    em.env_kwargs, em._eval_env_kwargs_args, em.verbose, em.n_timesteps = {}, None, 0, -1
    em.optimize_hyperparameters, em.n_evaluations, em.normalize, em.normalize_kwargs = False, None, False, {}
    em.monitor_kwargs, em.frame_stack, em.study_name, em.trial_id = {}, None, None, None
    hp, _ = em.read_hyperparameters()
    hp, *_ = em._preprocess_hyperparams(hp)
    spec = get_spec("residual-ppo")
    assert em.env_kwargs == env_kwargs_for(spec, "velocity", 2) and em.n_envs == spec.n_envs
    assert em.normalize_kwargs == {"norm_obs": True, "norm_reward": True, "clip_obs": 10.0, "gamma": spec.gamma}
    assert hp["policy"] is AgentMlpPolicy and hp["policy_kwargs"]["zero_init_action"] is True
    assert hp["learning_rate"](0.25) == 0.25 * spec.learning_rate
