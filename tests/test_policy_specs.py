"""Issue 16 bug 6: the harness neither guesses nor drops silently. A policy that acts on no evaluated task is an
error; an SB3 .zip without a saved env spec is scored with a printed warning (``residual-ppo:``/``ppo-direct:``) or
refused (``sb3:``); any SB3 algorithm loads by the generic ``sb3:`` prefix with its mode from the saved env spec;
a file that is not a model says so."""

import json
import warnings
from collections import OrderedDict

import gymnasium as gym
import pytest
import yaml
from stable_baselines3 import PPO, SAC, TD3

import ehss_gym  # noqa: F401  (registers the env id)
from ehss_gym import evaluation as ev
from ehss_gym.cli import main
from ehss_gym.envs import EHSSTrackingEnv
from ehss_gym.evaluation.loading import PolicyError, load_run, sb3_algorithm

TINY = ev.EvalConfig(suites=("heldout",), tasks=("velocity",), heldout_episodes=2, episode_seconds=0.3, n_boot=100)


def _save(model, path):
    model.save(str(path))
    return str(path)


def _ppo(mode="residual", task="velocity"):
    return PPO("MlpPolicy", EHSSTrackingEnv(mode=mode, task=task), n_steps=32, batch_size=32, device="cpu",
               policy_kwargs={"net_arch": [8]})


def test_a_policy_that_acts_on_no_evaluated_task_is_an_error(tmp_path, capsys):
    """Before: a velocity policy with --tasks position vanished from the report."""
    zp = _save(_ppo(), tmp_path / "vel.zip")
    (tmp_path / "vel.json").write_text(json.dumps({"env_kwargs": {"task": "velocity", "mode": "residual"}}))
    spec = ev.parse_policy(f"residual-ppo:{zp}")
    with pytest.raises(PolicyError, match=r"acts on task\(s\) velocity only.*evaluated tasks are position"):
        ev.evaluate([spec], ev.EvalConfig(suites=("heldout",), tasks=("position",)), workers=1, progress=False)
    rc = main(["evaluate", "--policies", f"residual-ppo:{zp}", "--task", "position", "--suite", "heldout",
               "--episodes", "1", "--out", str(tmp_path / "o"), "--store", str(tmp_path / "jobs"), "--no-progress"])
    assert rc == 2 and "would not be evaluated" in capsys.readouterr().err


def test_a_zip_without_its_env_spec_is_scored_with_a_printed_warning(tmp_path, capsys):
    """Before: the mode came silently from the name prefix (a residual-trained PPO was scored as ppo-direct)."""
    zp = _save(_ppo(), tmp_path / "lonely.zip")
    with pytest.warns(ev.PolicyWarning, match=r"no env spec saved with .*lonely.zip.*scored in mode 'direct'"):
        spec = ev.parse_policy(f"ppo-direct:{zp}")
    assert spec.env_kwargs["mode"] == "direct"
    with pytest.raises(PolicyError, match=r"no env spec saved with .*lonely.zip.*residual-ppo:PATH or ppo-direct"):
        ev.parse_policy(f"sb3:{zp}")
    rc = main(["evaluate", "--policies", f"ppo-direct:{zp}", "--suite", "heldout", "--task", "velocity",
               "--episodes", "1", "--out", str(tmp_path / "o"), "--store", str(tmp_path / "jobs"), "--no-progress"])
    assert rc == 0 and "ehss evaluate: warning: policy 'ppo-direct:" in capsys.readouterr().err


def test_a_saved_env_spec_names_the_mode_and_a_wrong_prefix_is_an_error(tmp_path):
    zp = _save(_ppo(), tmp_path / "res.zip")
    env = gym.make("EHSSTracking-v0", mode="residual", sigma=2e5)
    (tmp_path / "res.json").write_text(env.unwrapped.spec.to_json())  # Gymnasium's own EnvSpec JSON
    spec = ev.parse_policy(f"sb3:{zp}")
    assert spec.kind == "sb3" and spec.env_kwargs["mode"] == "residual" and spec.env_kwargs["sigma"] == 2e5
    assert spec.name == "sb3:res (residual)"
    with pytest.raises(PolicyError, match=r"trained with mode='residual'; name it residual-ppo:"):
        ev.parse_policy(f"ppo-direct:{zp}")


@pytest.mark.parametrize("algo", [SAC, TD3])
def test_any_sb3_algorithm_loads_by_the_generic_prefix(tmp_path, algo):
    """Before: SAC and TD3 models had to be passed as residual-ppo:PATH."""
    model = algo("MlpPolicy", EHSSTrackingEnv(mode="direct"), buffer_size=100, learning_starts=10, device="cpu",
                 policy_kwargs={"net_arch": [8]})
    zp = _save(model, tmp_path / f"{algo.__name__.lower()}.zip")
    (tmp_path / f"{algo.__name__.lower()}.json").write_text(json.dumps({"env_kwargs": {"mode": "direct"}}))
    assert sb3_algorithm(zp) == ("stable_baselines3", algo.__name__)
    spec = ev.parse_policy(f"sb3:{zp}")
    assert spec.env_kwargs["mode"] == "direct"
    assert type(load_run(zp, "velocity", spec.env_kwargs)) is algo
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a saved spec: nothing to warn about
        res = ev.evaluate([spec], TINY, workers=1, progress=False)
    assert {d["policy"] for d in res.summary} == {"clf-n2", spec.name}


def test_the_mode_is_read_from_rl_zoo3s_saved_arguments(tmp_path):
    run = tmp_path / "logs" / "ppo" / "EHSSTracking-v0_1"
    (run / "EHSSTracking-v0").mkdir(parents=True)
    zp = _save(_ppo(mode="direct"), run / "best_model.zip")
    args = OrderedDict([("algo", "ppo"), ("env", "EHSSTracking-v0"), ("env_kwargs", {"mode": "direct"})])
    (run / "EHSSTracking-v0" / "args.yml").write_text(yaml.dump(args))  # what rl-zoo3 writes: an OrderedDict
    assert "!!python/object/apply:collections.OrderedDict" in (run / "EHSSTracking-v0" / "args.yml").read_text()
    spec = ev.parse_policy(f"sb3:{zp}")
    assert spec.env_kwargs["mode"] == "direct"
    assert ev.saved_env_kwargs(zp)[1].endswith("args.yml")


def test_a_file_that_is_not_a_model_says_so(tmp_path, capsys):
    """Before: 'file not found' for a file that exists."""
    notes = tmp_path / "notes.txt"
    notes.write_text("hello")
    with pytest.raises(PolicyError, match=r"is not a model file: .*notes.txt"):
        ev.parse_policy(f"residual-ppo:{notes}")
    with pytest.raises(PolicyError, match=r"is a folder, not a model"):
        ev.parse_policy(f"sb3:{tmp_path}")
    fake = tmp_path / "fake.zip"
    fake.write_text("not a zip")
    (tmp_path / "fake.json").write_text(json.dumps({"env_kwargs": {}}))
    with pytest.raises(PolicyError, match=r"fake.zip is not a loadable stable-baselines3 model.*BadZipFile"):
        load_run(str(fake), "velocity", {})
    with pytest.raises(PolicyError, match=r"saved in .*other.json is of 'CartPole-v1'"):
        (tmp_path / "other.zip").write_bytes(fake.read_bytes())
        (tmp_path / "other.json").write_text(json.dumps({"id": "CartPole-v1", "kwargs": {}}))
        ev.parse_policy(f"sb3:{tmp_path / 'other.zip'}")


# --- labels: LABEL=SPEC ---------------------------------------------------------------------------------------


def _two_models_of_one_run(tmp_path):
    """A run folder with a final and a best policy (safe weights), as ehss train writes them."""
    from ehss_gym.agents.export import export_policy

    run = tmp_path / "residual-ppo-velocity-n2-seed0"
    for which in ("final", "best"):
        (run / which).mkdir(parents=True)
        export_policy(_ppo(), run / which / "policy", env_kwargs={"task": "velocity", "mode": "residual"})
    return run


def test_two_models_of_one_run_are_compared_under_their_labels(tmp_path, capsys):
    """Before: 'policy names must be unique' (both are named after the run folder), and no way to label them."""
    run = _two_models_of_one_run(tmp_path)
    same = [f"residual-ppo:{run}/final/policy", f"residual-ppo:{run}/best/policy"]
    with pytest.raises(PolicyError, match=r"more than once.*LABEL=SPEC"):
        ev.parse_policies(["clf-n2", *same])
    specs = ev.parse_policies(["clf-n2", f"final={same[0]}", f"best={same[1]}"])
    assert [s.name for s in specs] == ["clf-n2", "final", "best"]
    assert specs[1].runs == [f"{run}/final/policy"] and specs[2].runs == [f"{run}/best/policy"]
    assert specs[1].kind == "residual-ppo" and "final/policy" in specs[1].source
    rc = main(["evaluate", "--policies", "clf-n2", f"final={same[0]}", f"best={same[1]}", "--suite", "heldout",
               "--task", "velocity", "--episodes", "1", "--out", str(tmp_path / "o"), "--store",
               str(tmp_path / "jobs"), "--no-progress"])
    assert rc == 0, capsys.readouterr().err
    with open(tmp_path / "o" / "summary.csv") as f:
        assert {"final", "best", "clf-n2"} <= {line.split(",")[2] for line in f.readlines()[1:]}


@pytest.mark.parametrize("entries, needle", [
    (["=clf-n2"], r"the label before '=' is empty"),
    (["my law=clf-n4"], r"label 'my law' .*letters, digits"),
    (["a=b=clf-n4"], r"label 'b' .*one label"),
    (["clf-n2=clf-n4"], r"label 'clf-n2' .*is the name of a policy"),
    (["pid=clf-n4"], r"label 'pid' .*is the name of a policy"),
    (["A=clf-n4", "A=clf-n6"], r"policy name\(s\) \['A'\] given more than once"),
    (["clf-n4", "clf-n4"], r"\['clf-n4'\] given more than once.*LABEL=SPEC"),
    (["x=sac"], r"unknown policy 'sac'"),
])
def test_bad_or_duplicate_labels_are_refused_naming_them(entries, needle, tmp_path, capsys):
    with pytest.raises(PolicyError, match=needle):
        ev.parse_policies(entries)
    assert main(["evaluate", "--policies", *entries, "--out", str(tmp_path / "o"), "--store", str(tmp_path / "jobs"),
                 "--no-progress"]) == 2
    assert "error" in capsys.readouterr().err and not (tmp_path / "o").exists()
