"""Safe weights of a SAC actor (the squashed head): the export of SB3's SAC, its deterministic and stochastic actions
against SB3's and against an independent float64 reference, and the SAC variants the format refuses."""

import json
import os

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium import spaces

from ehss_gym.agents.export import export_policy, export_saved_model
from ehss_gym.agents.safeweights import LOG_STD_RANGE, SafeWeightsError, load_policy

pytestmark = pytest.mark.xdist_group("safeweights")

LOW = np.array([-1.0, 0.5], dtype=np.float32)  # a non-symmetric action Box: the rescale is not the identity
HIGH = np.array([3.0, 0.75], dtype=np.float32)
# the float64 reference against float32 torch: |difference| <= this times the action range (measured: 2.8e-6, the
# float32 rounding of the scaled-up mean layer's sums)
REF_RTOL = 1e-5


class BoxEnv(gym.Env):
    """A 3-D Box observation, the 2-D non-symmetric Box action; SAC only needs the spaces (no training here)."""

    observation_space = spaces.Box(-1e3, 1e3, shape=(3,), dtype=np.float32)
    action_space = spaces.Box(LOW, HIGH, dtype=np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return np.zeros(3, dtype=np.float32), {}

    def step(self, action):
        return np.zeros(3, dtype=np.float32), 0.0, False, False, {}


def _sac(**kwargs):
    from stable_baselines3 import SAC

    torch.set_num_threads(1)
    return SAC("MlpPolicy", BoxEnv(), seed=0, device="cpu", learning_starts=0, **kwargs)


@pytest.fixture(scope="module")
def sac(tmp_path_factory):
    """A randomly initialised SAC actor (hidden 32, 16, ReLU) with a scaled-up mean layer (so some actions saturate
    the tanh at the bounds) and VecNormalize statistics away from (0, 1)."""
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    model = _sac(policy_kwargs={"net_arch": [32, 16]})
    with torch.no_grad():
        model.policy.actor.mu.weight.mul_(20.0)
    venv = VecNormalize(DummyVecEnv([BoxEnv]), norm_reward=False)
    rng = np.random.default_rng(1)
    venv.obs_rms.mean = rng.normal(size=3) * [1.0, 5.0, -2.0]
    venv.obs_rms.var = rng.uniform(0.1, 30.0, size=3)
    stem = str(tmp_path_factory.mktemp("sac") / "sac")
    export_policy(model, stem, vecnormalize=venv, env_id="BoxEnv", env_kwargs={}, metadata={"algo": "sac"})
    return model, venv, stem


def _obs(n=2000, seed=0):
    # beyond the statistics too, so VecNormalize's clipping at 10 std is exercised
    return (np.random.default_rng(seed).normal(size=(n, 3)) * [3.0, 20.0, 60.0]).astype(np.float32)


def _reference(actor, obs_norm):
    """tanh(mu(latent_pi(obs))) rescaled to the Box, in float64 numpy from the actor's parameters (not through the
    export or the loader)."""
    h = obs_norm.astype(np.float32).astype(np.float64)  # the policy's input is float32, as SB3 casts it
    for m in actor.latent_pi:
        if isinstance(m, torch.nn.Linear):
            h = h @ m.weight.detach().double().numpy().T + m.bias.detach().double().numpy()
        else:
            assert isinstance(m, torch.nn.ReLU)
            h = np.maximum(h, 0.0)
    mean = h @ actor.mu.weight.detach().double().numpy().T + actor.mu.bias.detach().double().numpy()
    return LOW + 0.5 * (np.tanh(mean) + 1.0) * (HIGH.astype(np.float64) - LOW), h


def test_deterministic_actions_equal_sb3_and_the_reference(sac):
    model, venv, stem = sac
    pol = load_policy(stem)
    assert pol.head == "squashed"
    obs = _obs()
    norm = venv.normalize_obs(obs)
    assert (np.abs(norm) >= 10).any()  # VecNormalize's clip is exercised
    ref, _ = model.predict(norm, deterministic=True)
    got, state = pol.predict(obs)
    assert state is None and got.shape == ref.shape == (2000, 2) and got.dtype == np.float32
    # same torch float32 kernels as SB3's predict: identical on this machine (a tolerance of 0)
    assert np.array_equal(got, ref)
    for o in obs[:20]:  # single observations: the batch dimension removed as SB3 does
        r, _ = model.predict(venv.normalize_obs(o), deterministic=True)
        g, _ = pol.predict(o)
        assert g.shape == r.shape == (2,) and np.array_equal(g, r)
    expect, _ = _reference(model.policy.actor, norm)
    assert (np.abs(got - expect) <= REF_RTOL * (HIGH - LOW)).all()
    assert (got >= LOW).all() and (got <= HIGH).all()
    frac = (got - LOW) / (HIGH - LOW)  # where in each (non-symmetric) range: saturated and interior actions
    assert ((frac < 1e-3) | (frac > 1 - 1e-3)).any(axis=0).all() and ((frac > 0.1) & (frac < 0.9)).any(axis=0).all()


def test_architecture_record_and_tensors(sac):
    _, _, stem = sac
    cfg = json.loads(open(stem + ".json").read())
    assert cfg["architecture"] == {"obs_dim": 3, "hidden": [32, 16], "activation": "relu", "act_dim": 2,
                                   "head": "squashed"}
    pol = load_policy(stem)
    assert pol.tensors["log_std.weight"].shape == (2, 16) and pol.tensors["log_std.bias"].shape == (2,)
    assert "log_std" not in pol.tensors
    assert pol.metadata == {"algo": "sac"}


def test_without_vecnormalize(sac, tmp_path):
    model, _, _ = sac
    stem = str(tmp_path / "plain")
    export_policy(model.policy.actor, stem)  # the actor alone exports too
    pol = load_policy(stem)
    obs = _obs(300, seed=2) / 30
    assert pol.obs_normalization is None
    assert np.array_equal(pol.predict(obs)[0], model.predict(obs, deterministic=True)[0])


def test_stochastic_actions_are_the_squashed_gaussian(sac, tmp_path):
    """A sample, mapped back through the rescale and atanh, is Gaussian around the mean with the state-dependent
    std exp(clamp(log_std(latent))) computed from the torch modules."""
    _, venv, _ = sac
    model = _sac(policy_kwargs={"net_arch": [32, 16]})
    actor = model.policy.actor
    with torch.no_grad():  # a std of about 0.3 before the tanh, so few samples saturate
        actor.log_std.bias.sub_(1.2)
    export_policy(model, str(tmp_path / "s"), vecnormalize=venv)
    pol = load_policy(str(tmp_path / "s"))
    cand = _obs(400, seed=4)
    expect, _ = _reference(actor, venv.normalize_obs(cand))
    inner = np.all(np.abs((expect - LOW) / (HIGH - LOW) - 0.5) < 0.2, axis=1)  # mean well inside the Box
    i = int(np.argmax(inner))
    assert inner[i]
    obs = np.repeat(cand[i:i + 1], 20000, axis=0)
    sto, _ = pol.predict(obs, deterministic=False)
    det, _ = pol.predict(obs[:1])
    assert not np.array_equal(sto[0], sto[1]) and (sto >= LOW).all() and (sto <= HIGH).all()
    with torch.no_grad():
        o = torch.as_tensor(venv.normalize_obs(cand[i:i + 1])).float()
        latent = actor.latent_pi(o)
        mean = actor.mu(latent).numpy()[0].astype(np.float64)
        std = np.exp(np.clip(actor.log_std(latent).numpy()[0], *LOG_STD_RANGE)).astype(np.float64)
    u = np.arctanh(np.clip(2.0 * (sto.astype(np.float64) - LOW) / (HIGH - LOW) - 1.0, -1 + 1e-7, 1 - 1e-7))
    assert np.allclose(np.median(u, axis=0), mean, atol=0.05 * std)
    q25, q75 = np.quantile(u, [0.25, 0.75], axis=0)
    assert np.allclose((q75 - q25) / 1.349, std, rtol=0.05)
    assert np.allclose(np.arctanh(2.0 * (det.astype(np.float64) - LOW) / (HIGH - LOW) - 1.0), mean, atol=1e-4)


def test_refused_sac_variants_name_the_reason(tmp_path):
    from stable_baselines3.common.torch_layers import BaseFeaturesExtractor

    class Doubling(BaseFeaturesExtractor):
        def __init__(self, observation_space):
            super().__init__(observation_space, features_dim=3)

        def forward(self, obs):
            return 2.0 * obs

    with pytest.raises(SafeWeightsError, match="gSDE SAC actor"):
        export_policy(_sac(use_sde=True), str(tmp_path / "sde"))
    with pytest.raises(SafeWeightsError, match="only the flatten features extractor is supported, got Doubling"):
        export_policy(_sac(policy_kwargs={"features_extractor_class": Doubling}), str(tmp_path / "fx"))
    assert not any(p.endswith(".json") for p in os.listdir(tmp_path))


def test_shared_flatten_extractor_exports_the_same_actions(tmp_path):
    """A flatten extractor shared with the critics has no parameters: the actor's action is the same."""
    model = _sac(policy_kwargs={"net_arch": [8], "share_features_extractor": True})
    export_policy(model, str(tmp_path / "shared"))
    obs = _obs(200, seed=5) / 30
    assert np.array_equal(load_policy(str(tmp_path / "shared")).predict(obs)[0],
                          model.predict(obs, deterministic=True)[0])


def test_bad_head_and_gsde_squashed_refused(sac, tmp_path):
    import shutil

    from ehss_gym.agents.safeweights import sha256

    _, _, stem = sac
    for bad, match in (({"head": "beta"}, r"head must be one of \['squashed'\]"),
                       ({"head": "squashed", "exploration": "gsde"}, "has no squashed form")):
        dst = str(tmp_path / "m")
        shutil.copy(stem + ".safetensors", dst + ".safetensors")
        cfg = json.loads(open(stem + ".json").read())
        cfg["architecture"].update(bad)
        cfg["sha256"] = sha256(open(dst + ".safetensors", "rb").read())
        with open(dst + ".json", "w") as f:
            json.dump(cfg, f)
        with pytest.raises(SafeWeightsError, match=match):
            load_policy(dst)


def test_a_saved_run_folder_exports(sac, tmp_path):
    """``export_saved_model`` reads model.zip + vecnormalize.pkl + model.json as ``ehss train`` writes them."""
    import pickle

    model, venv, _ = sac
    folder = tmp_path / "best"
    folder.mkdir()
    model.save(str(folder / "model.zip"))
    with open(folder / "vecnormalize.pkl", "wb") as f:
        pickle.dump(venv, f)
    (folder / "model.json").write_text(json.dumps({"env_kwargs": {"task": "velocity"}}))
    stem = export_saved_model(str(folder), algo="sac", name="run0", metadata={"step": 5})
    pol = load_policy(stem)
    assert (pol.name, pol.env_kwargs["task"], pol.metadata) == ("run0", "velocity", {"step": 5})
    obs = _obs(300, seed=6)
    assert np.array_equal(pol.predict(obs)[0], model.predict(venv.normalize_obs(obs), deterministic=True)[0])
    (folder / "model.zip").write_bytes(b"")
    with pytest.raises(SafeWeightsError, match="cannot be read"):
        export_saved_model(str(folder), algo="sac", name="run0")
