"""The rl-zoo3 route of the README, end to end: a tiny ``python -m rl_zoo3.train`` run with the shipped config file,
then ``ehss evaluate`` on its model .zip and on its run folder, in the loop the run trained in.

The loop is checked against rl-zoo3's own reading of its records (``rl_zoo3.utils.get_saved_hyperparams`` and
``args.yml``, as ``rl_zoo3.enjoy`` replays a run), resolved by the env itself: a setting the records leave out takes
the env's current default, as it did in training.
"""

from __future__ import annotations

import csv
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
import yaml

from ehss_gym.cli import main
from ehss_gym.envs import ENV_ID, EHSSTrackingEnv, EnvConfig
from ehss_gym.envs.config import LEGACY_LOOP, POLICY_KEYS
from ehss_gym.evaluation import parse_policy
from ehss_gym.evaluation.loading import load_run
from ehss_gym.evaluation.specs import CONTROLLER_KEYS

zoo_utils = pytest.importorskip("rl_zoo3.utils")
pytestmark = pytest.mark.xdist_group("zoo")

# the README's command, shortened to one small rollout (rl-zoo3's --hyperparams override the config file's)
TRAIN = ["-m", "rl_zoo3.train", "--algo", "ppo", "--env", ENV_ID, "--gym-packages", "ehss_gym", "--conf-file",
         "ehss_gym.agents.hyperparams.ppo", "--seed", "0", "-n", "256", "--num-threads", "1", "--hyperparams",
         "n_envs:2", "n_steps:64", "batch_size:64", "n_epochs:1", "--log-folder", "logs"]


@pytest.fixture(scope="module")
def zoo_run(tmp_path_factory):
    """The run folder of a tiny rl-zoo3 training run (written under tmp_path, its working folder)."""
    root = tmp_path_factory.mktemp("zoo")
    r = subprocess.run([sys.executable, *TRAIN], cwd=root, capture_output=True, text=True, timeout=1200)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-3000:]
    run = root / "logs" / "ppo" / f"{ENV_ID}_1"
    assert (run / f"{ENV_ID}.zip").is_file() and (run / ENV_ID / "vecnormalize.pkl").is_file()
    return run


def policy_settings(cfg: EnvConfig) -> dict:
    """What a policy acts in (the env's policy settings; the episode's scenario holds arrays and is set per episode)."""
    return {k: getattr(cfg, k) for k in POLICY_KEYS}


def trained_loop(run) -> EnvConfig:
    """The env settings the run trained in, as rl-zoo3 replays them: its config's env_kwargs, replaced by
    ``--env-kwargs`` from args.yml when given, resolved by the env (missing settings: its defaults)."""
    hyperparams, _ = zoo_utils.get_saved_hyperparams(str(run / ENV_ID))
    kw = dict(hyperparams.get("env_kwargs", {}))
    args = yaml.load((run / ENV_ID / "args.yml").read_text(), Loader=yaml.UnsafeLoader)
    if args.get("env_kwargs"):
        kw = dict(args["env_kwargs"])
    return EnvConfig.from_kwargs(kw)


def scored_loop(spec, task="velocity") -> EnvConfig:
    return EnvConfig.from_kwargs(spec.env_kwargs_for(task))


def test_the_zoo_model_and_its_run_folder_are_read_in_the_loop_they_trained_in(zoo_run):
    want = trained_loop(zoo_run)
    default = EnvConfig.from_kwargs({"task": "velocity"})
    # the settings the config file leaves out are today's defaults, not the loop of older pinned formats
    for key in ("layer_gain", "pressure_domain"):
        assert getattr(want, key) == getattr(default, key) != LEGACY_LOOP[key]
    for text in (f"sb3:{zoo_run}/{ENV_ID}.zip", f"sb3:{zoo_run}", f"residual-ppo:{zoo_run}/{ENV_ID}.zip",
                 f"residual-ppo:{zoo_run}"):
        spec = parse_policy(text)
        assert spec.runs == [str(zoo_run / f"{ENV_ID}.zip")], text
        assert policy_settings(scored_loop(spec)) == policy_settings(want), text
        assert spec.tasks == ("velocity",) and spec.env_kwargs["mode"] == "residual"
    assert parse_policy(f"sb3:{zoo_run}").name == f"sb3:{ENV_ID}_1 (residual)"


def test_env_kwargs_given_on_rl_zoos_command_line_replace_the_config_files(zoo_run, tmp_path):
    """``--env-kwargs`` (recorded in args.yml) replaces the config file's env_kwargs as a whole, in training and
    here; the settings it leaves out are the env's defaults."""
    run = tmp_path / f"{ENV_ID}_1"
    shutil.copytree(zoo_run, run)
    args = yaml.load((run / ENV_ID / "args.yml").read_text(), Loader=yaml.UnsafeLoader)
    args["env_kwargs"] = {"task": "velocity", "mode": "residual", "n": 2, "agent_period": 20, "sigma": 2e5}
    (run / ENV_ID / "args.yml").write_text(yaml.dump(args))
    want = trained_loop(run)
    assert want.sigma == 2e5 and want.smoothing == EnvConfig.from_kwargs({"task": "velocity"}).smoothing
    assert policy_settings(scored_loop(parse_policy(f"sb3:{run}"))) == policy_settings(want)


def test_the_zoo_model_acts_on_observations_normalised_as_in_training(zoo_run):
    """rl-zoo3 keeps VecNormalize's statistics in <run>/EHSSTracking-v0/vecnormalize.pkl: the model sees
    observations normalised by them, as rl_zoo3.enjoy gives them."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    zp = str(zoo_run / f"{ENV_ID}.zip")
    spec = parse_policy(f"sb3:{zp}")
    policy = load_run(zp, "velocity", spec.env_kwargs_for("velocity"))
    venv = VecNormalize.load(str(zoo_run / ENV_ID / "vecnormalize.pkl"),
                             DummyVecEnv([lambda: EHSSTrackingEnv(**spec.env_kwargs_for("velocity"))]))
    model = PPO.load(zp, device="cpu")
    obs = np.stack([venv.envs[0].reset(seed=s)[0] for s in range(3)])
    assert not np.allclose(venv.normalize_obs(obs), obs)  # the statistics are not the identity
    want, _ = model.predict(venv.normalize_obs(obs), deterministic=True)
    got, _ = policy.predict(obs, deterministic=True)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-6)


def test_ehss_evaluate_scores_the_zoo_model_and_its_run_folder(zoo_run, tmp_path, capsys):
    """``ehss evaluate --quick`` on the .zip and on the folder: the same policy, scored in the loop it trained in (the
    recipe's is today's default loop: ranked with today's laws)."""
    want, default = trained_loop(zoo_run), EnvConfig.from_kwargs({"task": "velocity"})
    differ = [k for k in CONTROLLER_KEYS if getattr(want, k) != getattr(default, k)]
    scores = {}
    for form in (f"sb3:{zoo_run}/{ENV_ID}.zip", f"sb3:{zoo_run}"):
        out = tmp_path / str(len(scores))
        rc = main(["evaluate", "--quick", "--policies", form, "--suite", "heldout", "--task", "velocity",
                   "--out", str(out), "--store", str(tmp_path / "jobs"), "--no-progress"])
        assert rc == 0, capsys.readouterr().err
        with open(out / "summary.csv", newline="") as f:
            rows = {r["policy"]: r for r in csv.DictReader(f)}
        name = f"sb3:{ENV_ID}_1 (residual)"
        assert name in rows and np.isfinite(float(rows[name]["figure"]))
        # the recipe sets no law or loop setting: it trains and is scored in today's loop, ranked with today's laws,
        # and no law at other settings is added
        assert differ == [] and not [p for p in rows if "@" in p] and rows[name]["earlier_loop"] == "False"
        scores[form] = rows[name]["figure"]
    assert len(set(scores.values())) == 1  # one model, one loop: the same episodes
    assert os.listdir(tmp_path / "jobs")
