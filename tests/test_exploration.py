"""The exploration options of the training recipe: the colored-noise generator (its spectrum's slope against the power
law it is built for), pink-noise and gSDE PPO on the residual agent (the mean still starts at exactly 0; the trained
policy exports to safe weights and loads), and the recipe's files."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ehss_gym.agents.export import export_policy
from ehss_gym.agents.factory import ColoredGaussian, initial_mean_abs, make_agent, sde_log_std_init
from ehss_gym.agents.noise import ColoredNoise, powerlaw_noise
from ehss_gym.agents.safeweights import load_policy
from ehss_gym.agents.specs import get_spec
from ehss_gym.train.loop import make_env
from ehss_gym.train.zoo import hyperparams


def _slope(x: np.ndarray) -> float:
    """The log-log slope of the mean periodogram of sequences x (..., n) over 1/n .. 1/8 cycles per step, a
    least-squares fit on log-spaced bins (Welch's averaging over the batch)."""
    n = x.shape[-1]
    p = np.mean(np.abs(np.fft.rfft(x, axis=-1)) ** 2, axis=tuple(range(x.ndim - 1)))
    f = np.fft.rfftfreq(n)
    edges = np.logspace(np.log10(2.0 / n), np.log10(0.125), 20)
    fb, pb = [], []
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = (f >= lo) & (f < hi)
        if sel.any():
            fb.append(np.log(f[sel].mean()))
            pb.append(np.log(p[sel].mean()))
    return float(np.polyfit(fb, pb, 1)[0])


@pytest.mark.parametrize("beta", [0.0, 1.0, 2.0])
def test_the_noise_has_the_power_laws_slope_and_unit_variance(beta):
    x = powerlaw_noise(beta, 4096, (64,), np.random.default_rng(0))
    assert _slope(x) == pytest.approx(-beta, abs=0.1)
    assert np.var(x) == pytest.approx(1.0, rel=0.15 if beta < 2 else 0.5)  # red noise: few independent samples
    assert abs(np.mean(x)) < 0.1 * (1 + 5 * beta)


def test_the_process_hands_out_one_sequence_per_lane_and_renews_it():
    rng = np.random.default_rng(1)
    proc = ColoredNoise(1.0, 3, 2, 64, rng)
    steps = np.stack([proc.sample() for _ in range(200)], axis=-1)  # (3, 2, 200): across 3 sequences of 64
    assert steps.shape == (3, 2, 200)
    lag1 = np.mean(steps[..., 1:64] * steps[..., :63]) / np.mean(steps[..., :64] ** 2)
    assert lag1 > 0.3  # pink noise: successive samples are correlated (white: about 0)
    assert not np.allclose(steps[0, 0], steps[1, 0])
    with pytest.raises(ValueError, match="beta must be"):
        powerlaw_noise(-1.0, 8, (1,), rng)


SMALL = {"n_envs": 2, "n_steps": 64, "batch_size": 64, "n_epochs": 1,
         "env_kwargs": {"episode_seconds": 0.1, "action": "rate"}}


@pytest.fixture(scope="module", params=["gsde", "pink"])
def trained(request, tmp_path_factory):
    torch.set_num_threads(1)
    spec = get_spec("residual-ppo", exploration=request.param, **SMALL)
    venv = make_env({"task": "position", **spec.env_kwargs}, spec.n_envs, spec.gamma, spec.norm_reward)
    model = make_agent(spec, venv, seed=0)
    obs = venv.reset()
    start = (initial_mean_abs(model, obs), model.policy.log_std.detach().clone())
    model.learn(256)
    stem = str(tmp_path_factory.mktemp("expl") / "policy")
    export_policy(model, stem, vecnormalize=venv, env_kwargs={"task": "position", **spec.env_kwargs})
    return request.param, spec, model, venv, stem, start


def test_the_mean_starts_at_zero_and_the_noise_is_the_options(trained):
    kind, spec, model, _, _, start = trained
    mean0, log_std0 = start
    assert mean0 == 0.0  # the residual agent starts as its base law
    if kind == "gsde":
        assert model.use_sde and model.sde_sample_freq == spec.sde_sample_freq
        assert log_std0.shape == (64, 1) and torch.all(log_std0 == torch.tensor(sde_log_std_init(spec)).float())
    else:
        assert isinstance(model.policy.action_dist, ColoredGaussian)


def test_the_trained_policy_exports_and_loads_with_the_same_actions(trained):
    kind, _, model, venv, stem, _ = trained
    pol = load_policy(stem)
    obs = np.stack([venv.venv.reset() for _ in range(3)]).reshape(-1, venv.observation_space.shape[0])  # raw
    ref, _ = model.predict(venv.normalize_obs(obs), deterministic=True)
    got, _ = pol.predict(obs)
    assert np.allclose(got, ref, atol=1e-6)
    sto, _ = pol.predict(obs, deterministic=False)
    assert sto.shape == got.shape and not np.allclose(sto, got)
    assert (pol.tensors["log_std"].ndim == 2) == (kind == "gsde")


def test_the_recipe_files_carry_the_options():
    gsde = hyperparams(exploration="gsde")["EHSSTracking-v0"]
    assert gsde["use_sde"] is True and gsde["sde_sample_freq"] == 16
    assert f"log_std_init={sde_log_std_init(get_spec('residual-ppo')) !r}" in gsde["policy_kwargs"]
    pink = hyperparams(exploration="pink")["EHSSTracking-v0"]
    assert "noise_beta=1.0" in pink["policy_kwargs"] and "use_sde" not in pink
    assert "exploration" not in get_spec("residual-ppo").as_dict()  # the white-noise record as before the option
    assert get_spec("residual-ppo", exploration="pink").as_dict()["exploration"] == "pink"
    with pytest.raises(ValueError, match="exploration must be one of"):
        get_spec("residual-ppo", exploration="brown")
    with pytest.raises(ValueError, match="exploration must be one of"):
        get_spec("residual-sac", exploration="gsde")
