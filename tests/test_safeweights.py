"""Safe weights: export an SB3 policy as tensors + JSON, load it without unpickling (and without torch), refuse
tampered files."""

import json
import os
import pickle
import subprocess
import sys

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from ehss_gym.agents import safeweights as sw
from ehss_gym.agents.export import export_policy
from ehss_gym.agents.safeweights import SafeWeightsError, load_policy

pytestmark = pytest.mark.xdist_group("safeweights")  # one worker computes the trained model (a module fixture) once


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A small PPO trained for a few hundred steps on Pendulum-v1 with VecNormalize (statistics non-trivial)."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecNormalize

    torch.set_num_threads(1)
    venv = VecNormalize(make_vec_env("Pendulum-v1", n_envs=2, seed=0))
    model = PPO("MlpPolicy", venv, n_steps=64, batch_size=64, n_epochs=2, seed=0, device="cpu",
                policy_kwargs=dict(net_arch=[32, 16]))
    model.learn(256)
    with torch.no_grad():  # a large output layer, so some actions reach the clip at +-2 (SB3's predict clips)
        model.policy.action_net.weight.mul_(500.0)
    folder = tmp_path_factory.mktemp("sw")
    stem = str(folder / "pend")
    export_policy(model, stem, vecnormalize=venv, env_id="Pendulum-v1", env_kwargs={"g": 9.81},
                  metadata={"note": "test"})
    return model, venv, stem


def _obs(n=400, seed=0):
    # well beyond the running statistics, so VecNormalize's clipping at 10 std is exercised too
    return (np.random.default_rng(seed).normal(size=(n, 3)) * [1, 1, 50]).astype(np.float32)


def test_round_trip_identical_actions(trained):
    model, venv, stem = trained
    pol = load_policy(stem)
    obs = _obs()
    assert (np.abs(venv.normalize_obs(obs)) >= 10).any()  # clipping is exercised
    ref, _ = model.predict(venv.normalize_obs(obs), deterministic=True)
    got, state = pol.predict(obs)
    assert state is None
    assert got.shape == ref.shape == (400, 1)
    assert np.array_equal(got, ref)
    for o in obs[:20]:  # single observations: same values, batch dimension removed as SB3 does
        r, _ = model.predict(venv.normalize_obs(o), deterministic=True)
        g, _ = pol.predict(o)
        assert g.shape == r.shape == (1,)
        assert np.array_equal(g, r)
    mean = pol.mean_action(venv.normalize_obs(obs))
    assert (np.abs(mean) > 2).any(), "inputs should push some actions to the clip at +-2"


def test_contract_attributes(trained):
    _, _, stem = trained
    pol = load_policy(stem + ".json")  # either file name works
    assert pol.name == "pend"
    assert pol.env_kwargs == {"g": 9.81}
    assert pol.env_id == "Pendulum-v1"
    assert pol.metadata == {"note": "test"}
    assert pol.observation_space.shape == (3,) and pol.action_space.shape == (1,)
    assert float(pol.action_space.high[0]) == 2.0
    with pytest.raises(ValueError, match=r"observation must have shape \(3,\)"):
        pol.predict(np.zeros(4, dtype=np.float32))


def test_stochastic_predict_uses_log_std(trained):
    model, venv, stem = trained
    pol = load_policy(stem)
    cand = _obs(400, seed=3)
    mean = pol.mean_action(pol.normalize_obs(cand))[:, 0]
    i = int(np.argmin(np.abs(mean)))  # an observation whose mean action is well inside the bounds
    assert abs(mean[i]) < 1.0
    obs = np.repeat(cand[i:i + 1], 4000, axis=0)
    det, _ = pol.predict(obs)
    sto, _ = pol.predict(obs, deterministic=False)
    std = float(np.exp(model.policy.log_std.detach().numpy()[0]))
    assert np.all(det == det[0]) and not np.array_equal(det, sto)
    inside = np.abs(sto) < 2  # unclipped samples
    assert inside.mean() > 0.5
    assert abs(np.median(sto) - mean[i]) < 0.1 * std
    q25, q75 = np.quantile(sto, [0.25, 0.75])
    assert abs((q75 - q25) / 1.349 - std) < 0.1 * std  # Gaussian IQR, robust to the clipped tails


def test_sb3_evaluate_policy_accepts_it(trained):
    import gymnasium as gym
    from stable_baselines3.common.evaluation import evaluate_policy

    _, _, stem = trained
    pol = load_policy(stem)
    from stable_baselines3.common.monitor import Monitor

    mean, _ = evaluate_policy(pol, Monitor(gym.make("Pendulum-v1")), n_eval_episodes=1)
    assert np.isfinite(mean)


def test_no_vecnormalize_round_trip(trained, tmp_path):
    model, venv, _ = trained
    stem = str(tmp_path / "plain")
    export_policy(model, stem)
    pol = load_policy(stem)
    assert pol.obs_normalization is None
    obs = _obs(50, seed=1) / 50
    assert np.array_equal(pol.predict(obs)[0], model.predict(obs, deterministic=True)[0])


def test_loading_never_unpickles(trained, monkeypatch):
    model, venv, stem = trained

    def boom(*a, **k):
        raise AssertionError("unpickling attempted")

    monkeypatch.setattr(pickle, "load", boom)
    monkeypatch.setattr(pickle, "loads", boom)
    monkeypatch.setattr(pickle, "Unpickler", boom)
    monkeypatch.setattr(torch, "load", boom)
    pol = load_policy(stem)
    assert np.array_equal(pol.predict(_obs(10))[0], model.predict(venv.normalize_obs(_obs(10)), deterministic=True)[0])


def _copy(stem, tmp_path, name="m"):
    st, js = sw.model_paths(stem)
    dst = str(tmp_path / name)
    with open(st, "rb") as f:
        blob = f.read()
    with open(dst + ".safetensors", "wb") as f:
        f.write(blob)
    with open(js) as f:
        cfg = json.load(f)
    with open(dst + ".json", "w") as f:
        json.dump(cfg, f)
    return dst, blob, cfg


def _rewrite(dst, tensors, cfg, fix_hash=True):
    from safetensors.torch import save

    blob = save(tensors)
    with open(dst + ".safetensors", "wb") as f:
        f.write(blob)
    if fix_hash:
        cfg = dict(cfg, sha256=sw.sha256(blob))
    with open(dst + ".json", "w") as f:
        json.dump(cfg, f)


def test_tampered_bytes_refused(trained, tmp_path):
    dst, blob, _ = _copy(trained[2], tmp_path)
    bad = bytearray(blob)
    bad[-3] ^= 0x01  # one bit of one weight
    with open(dst + ".safetensors", "wb") as f:
        f.write(bytes(bad))
    with pytest.raises(SafeWeightsError, match="SHA-256 .* does not match"):
        load_policy(dst)


def test_extra_tensor_refused_even_with_matching_hash(trained, tmp_path):
    from safetensors.torch import load

    dst, blob, cfg = _copy(trained[2], tmp_path)
    t = load(blob)
    t["payload"] = torch.zeros(3)
    _rewrite(dst, t, cfg)
    with pytest.raises(SafeWeightsError, match=r"unexpected \['payload'\]"):
        load_policy(dst)


def test_wrong_shape_refused(trained, tmp_path):
    from safetensors.torch import load

    dst, blob, cfg = _copy(trained[2], tmp_path)
    t = load(blob)
    t["action.weight"] = torch.zeros(1, 17)
    _rewrite(dst, t, cfg)
    with pytest.raises(SafeWeightsError, match="'action.weight' must have shape"):
        load_policy(dst)


def test_missing_tensor_and_nonfinite_refused(trained, tmp_path):
    from safetensors.torch import load

    dst, blob, cfg = _copy(trained[2], tmp_path)
    t = load(blob)
    del t["obs_var"]
    _rewrite(dst, t, cfg)
    with pytest.raises(SafeWeightsError, match=r"missing \['obs_var'\]"):
        load_policy(dst)
    t = load(blob)
    t["pi.0.bias"][0] = float("nan")
    _rewrite(dst, t, cfg)
    with pytest.raises(SafeWeightsError, match="non-finite"):
        load_policy(dst)


def test_bad_json_refused(trained, tmp_path):
    dst, _, cfg = _copy(trained[2], tmp_path)
    for change, match in (({"exploit": "x"}, r"unexpected \['exploit'\]"),
                          ({"format": "other/9"}, "format must be"),
                          ({"architecture": {**cfg["architecture"], "activation": "os.system"}}, "activation must be"),
                          ({"sha256": "zz"}, "sha256 must be 64")):
        with open(dst + ".json", "w") as f:
            json.dump({**cfg, **change}, f)
        with pytest.raises(SafeWeightsError, match=match):
            load_policy(dst)
    with open(dst + ".json", "w") as f:
        f.write("{not json")
    with pytest.raises(SafeWeightsError, match="not valid JSON"):
        load_policy(dst)


def test_missing_file_refused(tmp_path):
    with pytest.raises(SafeWeightsError, match="not found"):
        load_policy(str(tmp_path / "nothing"))


def test_export_refuses_unsupported_policies(tmp_path):
    import gymnasium as gym
    from stable_baselines3 import PPO

    model = PPO("MlpPolicy", gym.make("Pendulum-v1"), use_sde=True, n_steps=64, batch_size=64, device="cpu",
                policy_kwargs={"use_expln": True})  # gSDE exports with SB3's defaults (tests/test_exploration.py)
    with pytest.raises(SafeWeightsError, match="gSDE policy is supported with SB3's defaults only"):
        export_policy(model, str(tmp_path / "sde"))
    assert not os.path.exists(tmp_path / "sde.json")


def test_wrong_dtype_refused(trained, tmp_path):
    from safetensors.torch import load

    dst, blob, cfg = _copy(trained[2], tmp_path)
    t = load(blob)
    t["action.bias"] = t["action.bias"].double()
    _rewrite(dst, t, cfg)
    with pytest.raises(SafeWeightsError, match=r"'action.bias' must have shape \(1,\) and dtype float32, got \(1,\) "
                                               "float64"):
        load_policy(dst)


def test_loading_a_shipped_policy_needs_no_torch():
    """load_policy parses and checks with numpy only; torch comes in with the first forward pass (its float32
    kernels are what SB3's predict runs)."""
    code = ("import sys; from ehss_gym.agents.safeweights import load_policy, shipped_models; "
            "p = load_policy(shipped_models()['residual-ppo-velocity-n2-seed1']); loaded = 'torch' in sys.modules; "
            "import numpy as np; a = p.predict(np.zeros(p.observation_space.shape, np.float32))[0]; "
            "print(loaded, 'torch' in sys.modules, a.shape == p.action_space.shape)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=True)
    assert out.stdout.split() == ["False", "True", "True"]


def test_loaded_policy_pickles_without_torch_objects(trained):
    """The evaluation sends loaded policies to its workers as pickles: the tensors are numpy arrays."""
    model, venv, stem = trained
    pol = pickle.loads(pickle.dumps(load_policy(stem)))
    assert all(isinstance(v, np.ndarray) for v in pol.tensors.values())
    obs = _obs(20)
    assert np.array_equal(pol.predict(obs)[0], model.predict(venv.normalize_obs(obs), deterministic=True)[0])


def test_a_policy_that_has_predicted_pickles_and_predicts_the_same(trained):
    """The forward pass is made once, at the first predict, and kept (no torch tensors rebuilt each call); a policy
    that has predicted still pickles (the pass is not pickled, but made again) and predicts the same, bit for bit."""
    model, venv, stem = trained
    pol = load_policy(stem)
    obs = _obs(20)
    first = pol.predict(obs)[0]
    forward = pol._torch_fn
    assert forward is not None and np.array_equal(pol.predict(obs)[0], first) and pol._torch_fn is forward
    back = pickle.loads(pickle.dumps(pol))
    assert back._torch_fn is None and np.array_equal(back.predict(obs)[0], first)
    assert np.array_equal(first, model.predict(venv.normalize_obs(obs), deterministic=True)[0])


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), B=st.integers(1, 9), D=st.integers(1, 6), clip=st.sampled_from([0.5, 5.0, 10.0]),
       dtype=st.sampled_from([np.float32, np.float64]))
def test_the_compiled_normalisation_is_vecnormalizes_arithmetic_bit_for_bit(seed, B, D, clip, dtype):
    """normalize_into against VecNormalize's own expression (np.clip of the float64 quotient, then float32), on
    values that reach the clip exactly, beyond it, NaN, infinities and signed zeros."""
    rng = np.random.default_rng(seed)
    mean, var = rng.normal(size=D) * 3, rng.uniform(1e-6, 20.0, D)
    std = np.sqrt(var + 1e-8)
    obs = (mean + std * rng.choice([-clip, clip, -2 * clip, 0.3, -0.0], size=(B, D))).astype(dtype)
    obs[rng.random((B, D)) < 0.15] = rng.choice([np.nan, np.inf, -np.inf, -0.0, 0.0])
    obs += (rng.normal(size=(B, D)) * (rng.random((B, D)) < 0.3)).astype(dtype)
    want = np.clip((obs - mean) / std, -clip, clip).astype(np.float32)
    got = np.full((B, D), 7.0, dtype=np.float32)
    sw.normalize_into(obs, mean, std, clip, got)
    assert np.array_equal(got, want, equal_nan=True)
    assert np.array_equal(np.signbit(got), np.signbit(want))


def test_normalising_an_observation_of_the_wrong_size_names_it(trained):
    """normalize_obs reads rows of obs_dim entries: another last dimension is refused, not reshaped into rows."""
    _, _, stem = trained
    pol = load_policy(stem)
    with pytest.raises(ValueError, match=r"observation must have shape \(3,\) or \(\.\.\., 3\)"):
        pol.normalize_obs(np.zeros((2, 6), np.float32))  # 12 entries would make 4 rows of 3
    with pytest.raises(ValueError, match="observation must have shape"):
        pol.normalize_obs(np.float32(1.0))
    assert pol.normalize_obs(np.zeros((2, 4, 3), np.float32)).shape == (2, 4, 3)
