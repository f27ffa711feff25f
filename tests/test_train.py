"""Training: options from the Config dataclass, seed parsing, run names, the CLI's bad-input errors, the native
vector env against SB3's DummyVecEnv, a smoke run, resume after kill -9, the report's analyses and template."""

import argparse
import ast
import dataclasses
import json
import os
import pathlib
import signal
import subprocess
import sys
import time

import gymnasium as gym
import numpy as np
import pytest
import torch
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv

from ehss_gym.agents.factory import make_agent
from ehss_gym.agents.specs import env_kwargs_for, get_spec
from ehss_gym.cli import main as cli_main
from ehss_gym.reporting import training as report_writer
from ehss_gym.train import launch, options, runs
from ehss_gym.train.callbacks import capture_rng, restore_rng
from ehss_gym.train.config import Config, Launch, build_parser, config_from_args
from ehss_gym.train.loop import make_env
from ehss_gym.train.vec_env import NativeVecEnv

ROOT = pathlib.Path(__file__).resolve().parents[1]

# A tiny but complete run: 2 envs x 64 steps per rollout, 1 validation episode.
TINY = ["--n-envs", "2", "--hp", "n_steps=64", "--hp", "batch_size=64", "--hp", "n_epochs=1", "--eval-episodes", "1",
        "--eval-seconds", "0.6", "--no-progress"]


# --- seeds, names ----------------------------------------------------------------------------------


def test_parse_seeds_forms():
    assert runs.parse_seeds("3") == [3]
    assert runs.parse_seeds("0-4") == [0, 1, 2, 3, 4]
    assert runs.parse_seeds("7, 0-2") == [0, 1, 2, 7]


@pytest.mark.parametrize("text, match", [("4-0", "start > end"), ("a", "bad item 'a'"), ("", "must be like"),
                                         ("-1", "bad item '-1'"), ("1-", "bad item '1-'"),
                                         ("0-10000", r"integers in \[0, 10000\)"), ("1,,2", "bad item ''"),
                                         ("0,0", "seed 0 twice"), ("0-2, 7,2", "seed 2 twice")])
def test_parse_seeds_bad(text, match):
    with pytest.raises(runs.RunError, match=match):
        runs.parse_seeds(text)


def test_run_name_reproducible_and_sensitive():
    a = Config(seed=1)
    assert a.run_name() == Config(seed=1).run_name()
    assert a.run_name().startswith("residual-ppo_velocity_n2_s1_")
    assert Config(seed=1, out="x", progress=False, timesteps=5).run_name() == a.run_name()  # not result-changing
    assert Config(seed=1, hp={"gamma": 0.99}).run_name() != a.run_name()
    assert Config(seed=2).run_name() != a.run_name()
    assert Config(agent="ppo", seed=1).run_name().startswith("ppo_velocity_n2_s1_")


# --- bad input: exit code 2 with a message naming the parameter -------------------------------------


@pytest.mark.parametrize("argv, match", [
    (["--agent", "sac"],
     r"argument --agent: invalid choice: 'sac' \(choose from 'ppo', 'residual-ppo', 'residual-ppo-eso', "
     r"'residual-sac'\)"),
    (["--agent", "residual-ppo-eso", "--task", "position"],
     r"--task must be one of \['velocity'\] for agent 'residual-ppo-eso'"),
    (["--seeds", "4-0"], "--seeds range '4-0' has start > end"),
    (["--seeds", "x"], "--seeds must be like"),
    (["--seed", "1", "--seeds", "0-1"], "either --seed or --seeds"),
    (["--n", "3"], "--n must be an even integer >= 2"),
    (["--task", "torque"], "argument --task: invalid choice: 'torque'"),
    (["--timesteps", "0"], "--timesteps must be an integer >= 1"),
    (["--hp", "gamma"], "--hp must be KEY=JSON"),
    (["--hp", "nope=1"], r"unknown or fixed agent hyperparameter\(s\) \['nope'\]"),
    (["--workers", "0", "--seeds", "0-1"], "--workers must be an integer >= 1"),
    (["--eval-seconds", "0"], r"--eval-seconds must be a number in \[0.01, 100\]"),
])
def test_cli_bad_input_exit_2(argv, match, capsys, tmp_path):
    """Bad values exit with 2 and name the option: the choices checked by argparse, the rest by the run's checks."""
    try:
        rc = cli_main(["train", "--out", str(tmp_path / "r"), *argv])
    except SystemExit as exc:
        rc = exc.code
    assert rc == 2
    err = capsys.readouterr().err
    assert "ehss train: error:" in err
    assert __import__("re").search(match, err), err


def test_resume_without_checkpoint_exit_2(capsys, tmp_path):
    assert cli_main(["train", "--out", str(tmp_path / "none"), "--resume"]) == 2
    assert "--resume: no checkpoint in" in capsys.readouterr().err
    assert cli_main(["train", "--seeds", "0-1", "--out", str(tmp_path / "none"), "--resume"]) == 2
    assert "no checkpoint in" in capsys.readouterr().err


# --- checkpoints (no env needed) ----------------------------------------------------------------------


def test_rng_capture_restore_round_trip():
    import random

    g = [np.random.default_rng(5), np.random.default_rng(6)]
    st = json.loads(json.dumps(capture_rng(g)))  # survives JSON
    want = (random.random(), np.random.rand(), torch.rand(1).item(), g[0].random(), g[1].random())
    random.random(), np.random.rand(), torch.rand(1), g[0].random(), g[1].random()  # move on
    restore_rng(st, g)
    assert (random.random(), np.random.rand(), torch.rand(1).item(), g[0].random(), g[1].random()) == want


def test_latest_checkpoint_needs_complete_files(tmp_path):
    d = str(tmp_path)
    assert runs.latest_checkpoint(d) is None
    os.makedirs(runs.checkpoint_dir(d))
    with open(os.path.join(runs.checkpoint_dir(d), runs.LATEST), "w") as f:
        json.dump({"step": 64}, f)
    with pytest.raises(runs.RunError, match="names step 64 but"):
        runs.latest_checkpoint(d)


# --- a real run ---------------------------------------------------------------------------------------


def test_training_smoke(tmp_path):
    """A few hundred steps: every output exists and the safe weights reproduce the SB3 model's actions."""
    import pickle

    from stable_baselines3 import PPO

    from ehss_gym.agents.safeweights import load_policy
    from ehss_gym.agents.specs import resolved_env_kwargs
    from ehss_gym.envs import EHSSTrackingEnv
    from ehss_gym.study import training as analysis

    out = tmp_path / "run"
    rc = cli_main(["train", "--timesteps", "256", "--eval-freq", "128", "--checkpoint-freq", "128", "--out", str(out),
                   *TINY])
    assert rc == 0
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["agent_spec"]["n_steps"] == 64 and cfg["env_kwargs"]["mode"] == "residual"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["timesteps"] == 256 and summary["wall_s"] > 0
    assert summary["best_is_untrained"] == (summary["best_step"] == 0)
    hist = json.loads((out / "evaluations.json").read_text())
    assert [r["step"] for r in hist] == [0, 128, 256]
    # step 0 is exactly the base law: every class figure against it is 1, and it passes the gate
    rel = [hist[0][f"rel_{c}"] for c in ("tracking", "disturbance", "effort", "chatter")]
    assert set(rel) <= {1.0, None} and 1.0 in rel  # None: a class with no episode in this tiny validation
    assert not hist[0]["failed"] and hist[0]["figure"] is not None
    assert any(f.startswith("events.out.tfevents") for _, _, fs in os.walk(out / "tb") for f in fs)
    assert runs.latest_checkpoint(str(out))["step"] == 256
    for sub in ("best", "final"):
        assert (out / sub / "model.zip").is_file() and (out / sub / "vecnormalize.pkl").is_file()
    pol = load_policy(str(out / "final" / "policy"))
    assert pol.metadata["step"] == 256
    assert pol.env_kwargs == resolved_env_kwargs(cfg["env_kwargs"])  # every env setting pinned, defaults included
    assert pol.env_kwargs["residual_scale"] == 10.0 and pol.env_kwargs["control_period"] > 0
    model = PPO.load(str(out / "final" / "model.zip"), device="cpu")
    env = EHSSTrackingEnv(**pol.env_kwargs)
    with open(out / "final" / "vecnormalize.pkl", "rb") as f:
        vn = pickle.load(f)
    obs = []
    o, _ = env.reset(seed=3)
    for _ in range(200):
        obs.append(o)
        o, *_ = env.step(pol.predict(o)[0])
    obs = np.array(obs)
    ref = model.predict(vn.normalize_obs(obs), deterministic=True)[0]
    assert np.array_equal(pol.predict(obs)[0], ref)
    assert np.abs(ref).max() > 0  # the trained policy is not the zero residual any more
    # a second start in the same folder is refused: it would overwrite the run
    assert cli_main(["train", "--timesteps", "256", "--out", str(out), *TINY]) == 2
    # the report's helpers on this run: grouping, learning curves, shipping as safe weights
    groups = analysis.group_runs(analysis.load_runs(str(tmp_path)))
    assert [k[:3] for k in groups] == [("residual-ppo", "velocity", 2)]
    assert json.loads(list(groups)[0][3]) == {"batch_size": 64, "n_epochs": 1, "n_steps": 64}  # the --hp variant
    key = list(groups)[0]
    report_writer.plot_curve(key, groups[key], str(tmp_path / "curves.png"))
    assert (tmp_path / "curves.png").stat().st_size > 1000
    # one seed is no shippable group (the rule asks for 4 trained seeds); its kept policy copied as one shipment would
    shipment = analysis.ship(groups, str(tmp_path / "models"), made_by="test")
    assert shipment.written == [] and "at least 4" in dict(shipment.skipped)[analysis.label(key)]
    models = str(tmp_path / "models")
    shipped = [analysis.ship_run(groups[key][0], "residual-ppo-velocity-n2-seed0", models, made_by="test")]
    assert [os.path.basename(p) for p in shipped] == ["residual-ppo-velocity-n2-seed0"]
    ship_pol = load_policy(shipped[0])
    assert ship_pol.name == "residual-ppo-velocity-n2-seed0" and ship_pol.metadata["made_by"].endswith("by test")
    best = load_policy(str(out / "best" / "policy"))
    assert np.array_equal(ship_pol.predict(obs)[0], best.predict(obs)[0])
    # shipping the same model again leaves the files as they are (made_by records the first shipping)
    stamp = os.stat(shipped[0] + ".json").st_mtime_ns
    assert analysis.ship_run(groups[key][0], "residual-ppo-velocity-n2-seed0", models, "another command") == shipped[0]
    assert os.stat(shipped[0] + ".json").st_mtime_ns == stamp and load_policy(shipped[0]).metadata == ship_pol.metadata


def test_noop_resume_keeps_the_checkpoint_and_the_best_models(tmp_path, capsys):
    """Issue 16, bug 1: a resume with nothing left to train used to save a checkpoint labelled step 0, so the
    next resume deleted every best model above it and crashed looking for evals/best_step_<S>/model.zip."""
    out = str(tmp_path / "r")
    base = ["train", "--eval-freq", "128", "--checkpoint-freq", "128", "--out", out, *TINY]
    assert cli_main([*base, "--timesteps", "256"]) == 0
    best = sorted(os.listdir(os.path.join(out, "evals")))
    assert cli_main([*base, "--timesteps", "256", "--resume"]) == 0
    assert "nothing to train" in capsys.readouterr().err
    assert runs.latest_checkpoint(out)["step"] == 256 and sorted(os.listdir(os.path.join(out, "evals"))) == best
    assert cli_main([*base, "--timesteps", "384", "--resume"]) == 0
    assert json.loads(open(os.path.join(out, "summary.json")).read())["timesteps"] == 384


def test_timesteps_rounded_to_a_rollout_are_announced(tmp_path, capsys):
    """Issue 16, bug 7: PPO trains whole rollouts; a --timesteps that is not a multiple says what will run."""
    from ehss_gym.train.loop import rollout_note

    assert rollout_note(4096, 0, 2048) is None
    assert "training runs to step 4096" in rollout_note(3000, 0, 2048)
    assert "training runs to step 3072" in rollout_note(3000, 1024, 2048)
    assert "nothing to train" in rollout_note(3000, 4096, 2048)
    out = str(tmp_path / "r")
    assert cli_main(["train", "--timesteps", "200", "--eval-freq", "128", "--out", out, *TINY]) == 0
    assert "--timesteps 200 is not a whole number of rollouts (128 agent steps" in capsys.readouterr().err
    assert json.loads(open(os.path.join(out, "summary.json")).read())["timesteps"] == 256


def test_training_other_base_law(tmp_path):
    """n = 4: the figure's reference is still the n = 2 law on the same episodes."""
    out = tmp_path / "n4"
    assert cli_main(["train", "--n", "4", "--timesteps", "128", "--eval-freq", "128", "--out", str(out), *TINY]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["n"] == 4 and s["base_validation"]["rel_disturbance"] == 1.0
    assert s["base_validation"]["figure"] != 1.0  # the n = 4 law against the n = 2 reference


def test_training_on_a_compensator_with_the_compensation_action(tmp_path):
    """A residual on top of a scripted compensator, scaling it (the compensation action): it starts as the compensated
    law (its step-0 classes are its base law's), and its figures' reference is the n = 2 law without the compensator
    and without the action (which needs one), so it is not 1."""
    out = tmp_path / "comp"
    hp = ('{"action": "compensation", "inverse_threshold": 0.375, "inverse_hysteresis": 2.25, '
          '"unmodelled_effects": true}')
    assert cli_main(["train", "--timesteps", "128", "--eval-freq", "128", "--out", str(out), *TINY,
                     "--hp", f"env_kwargs={hp}"]) == 0
    s = json.loads((out / "summary.json").read_text())
    hist = json.loads((out / "evaluations.json").read_text())
    assert hist[0]["figure"] == s["base_validation"]["figure"] != 1.0
    assert {hist[0][f"rel_{c}"] for c in ("tracking", "disturbance", "effort", "chatter")} <= {1.0, None}


def test_resume_after_sigkill(tmp_path):
    """Kill -9 a training process after its first checkpoint; --resume continues the step count."""
    out = tmp_path / "run"
    argv = [sys.executable, "-m", "ehss_gym.train.loop", "--timesteps", "1000000", "--eval-freq", "100000",
            "--checkpoint-freq", "128", "--out", str(out), *TINY]
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            env={**os.environ, "OMP_NUM_THREADS": "1"})
    try:
        t0 = time.time()
        while runs.latest_checkpoint(str(out)) is None:
            assert proc.poll() is None, proc.stderr.read().decode()
            assert time.time() - t0 < 300, "no checkpoint within 300 s"
            time.sleep(0.2)
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    man = runs.latest_checkpoint(str(out))
    step = man["step"]
    assert step >= 128
    state = runs.read_state(man["state"])
    assert state["num_timesteps"] == step
    target = step + 256
    rc = cli_main(["train", "--timesteps", str(target), "--eval-freq", "100000", "--checkpoint-freq", "128",
                   "--out", str(out), "--resume", *TINY])
    assert rc == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["timesteps"] == target  # continued from the checkpoint, not from 0
    hist = json.loads((out / "evaluations.json").read_text())
    assert hist[0]["step"] == 0 and hist[-1]["step"] == target  # history kept across the kill
    assert summary["wall_s"] >= state["callbacks"]["wall"]["seconds"]
    # resuming changed settings is refused
    assert cli_main(["train", "--timesteps", str(target), "--out", str(out), "--resume", *TINY,
                     "--hp", "gamma=0.9"]) == 2


def test_multi_seed_makes_one_job_per_seed(tmp_path, monkeypatch, capsys):
    """--seeds makes one training job per seed on the chosen backend, each with its seed and run folder, in fresh
    worker processes, at most --jobs at a time (the jobs faked here; the Ray tests train two for real)."""
    seen = {}

    def fake_map(self, jobs, context=None, desc="jobs", fresh_process=False, in_process=None):
        seen.update(jobs=jobs, fresh=fresh_process, workers=self.backend.workers, backend=self.backend.name)
        self.computed += len(jobs)
        return [{"summary": {"run_dir": j.config["out"], "run_name": os.path.basename(j.config["out"]),
                             "timesteps": 64, "wall_s": 0.0, "best_step": 0, "best_validation": VAL,
                             "base_validation": VAL, "final_validation": {**VAL, "step": 64}}, "weights": {}}
                for j in jobs]

    monkeypatch.setattr(launch.Executor, "map", fake_map)
    assert cli_main(["train", "--seeds", "0-2", "--workers", "2", "--out", str(tmp_path), "--timesteps", "64",
                     *TINY]) == 0
    jobs = seen["jobs"]
    assert [j.seed for j in jobs] == [0, 1, 2] and seen["fresh"] and seen["workers"] == 2
    assert seen["backend"] == "local"
    tiny = dict(n_envs=2, eval_episodes=1, eval_seconds=0.6, hp={"n_steps": 64, "batch_size": 64, "n_epochs": 1})
    outs = [j.config["out"] for j in jobs]
    assert all(os.path.dirname(o) == str(tmp_path) for o in outs)
    assert all(os.path.basename(o) == Config(seed=s, **tiny).run_name() for o, s in zip(outs, (0, 1, 2)))
    # each job's config rebuilds its Config exactly (the seed passed on its own)
    for j, o in zip(jobs, outs):
        assert Config(**j.config, seed=j.seed) == Config(seed=j.seed, out=o, timesteps=64, **tiny)
    assert "3 seed(s) trained" in capsys.readouterr().out


VAL = {"figure": 1.0, "failed": False, "n_failed": 0, "rel_tracking": 1.0, "rel_disturbance": 1.0, "rel_effort": 1.0,
       "rel_chatter": 1.0}


def test_residual_sac_smoke(tmp_path, capsys):
    """The comparison algorithm through the same ``ehss train``: SAC starts as the base law (figure 1 at step 0),
    exports its SB3 files with every env setting (model.json) and its safe weights (the squashed head, the SB3 model's
    actions), and is scored in today's loop."""
    from stable_baselines3 import SAC

    from ehss_gym.evaluation.scoring import is_earlier_loop
    from ehss_gym.evaluation.specs import parse_policy

    out = tmp_path / "sac"
    rc = cli_main(["train", "--agent", "residual-sac", "--timesteps", "256", "--eval-freq", "128", "--out", str(out),
                   "--n-envs", "2", "--hp", "learning_starts=64", "--hp", "batch_size=32", "--hp", "buffer_size=1000",
                   "--eval-episodes", "1", "--eval-seconds", "0.6", "--no-progress"])
    assert rc == 0
    printed = capsys.readouterr().out
    assert "best  (step" in printed and "final (step 256)" in printed and "safe weights" in printed
    summary = json.loads((out / "summary.json").read_text())
    assert summary["algo"] == "sac" and summary["timesteps"] == 256
    hist = json.loads((out / "evaluations.json").read_text())
    rel = [hist[0][f"rel_{c}"] for c in ("tracking", "disturbance", "effort", "chatter")]
    assert set(rel) <= {1.0, None} and 1.0 in rel  # step 0: the base law exactly
    model = SAC.load(str(out / "final" / "model.zip"), device="cpu")
    assert model.num_timesteps == 256
    kw = json.loads((out / "final" / "model.json").read_text())["env_kwargs"]
    assert kw["memory_tau"] == 0.1 and kw["reward_weights"]["physical"] == 1.0 and kw["bumpless"] is True
    assert not is_earlier_loop(parse_policy(f"sb3:{out}/final/model.zip"), "velocity")
    import pickle

    from ehss_gym.agents.safeweights import load_policy

    for folder in ("best", "final"):
        pol = load_policy(str(out / folder / "policy"))
        assert pol.head == "squashed" and pol.env_kwargs == kw
    with open(out / "final" / "vecnormalize.pkl", "rb") as f:
        vn = pickle.load(f)
    env = pol.make_env()
    obs = [env.reset(seed=s)[0] for s in range(4)]
    obs += [env.step(env.action_space.sample())[0] for _ in range(60)]
    obs = np.stack(obs).astype(np.float32)
    ref, _ = model.predict(vn.normalize_obs(obs), deterministic=True)
    assert np.array_equal(pol.predict(obs)[0], ref)
    assert not is_earlier_loop(parse_policy(f"residual-ppo:{out}/final/policy"), "velocity")


def test_run_summary_prints_the_best_and_the_final_policy_and_flags_an_untrained_best():
    from ehss_gym.train.loop import describe

    worse = {**VAL, "figure": 5.3, "rel_effort": 12.0, "step": 20480}
    s = {"run_name": "r", "run_dir": "d", "timesteps": 20480, "wall_s": 60.0, "best_step": 0,
         "best_validation": {**VAL, "step": 0}, "best_is_untrained": True, "base_validation": VAL,
         "final_validation": worse}
    text = describe(s)
    assert "best  (step 0): validation figure 1.0000" in text and "final (step 20480): validation figure 5.3000" in text
    assert "effort x12.000" in text and "the best is the untrained step-0 policy" in text
    assert "the base law itself" in describe({**s, "agent": "residual-ppo"})
    assert "randomly initialised" in describe({**s, "agent": "ppo"})
    assert "untrained" not in describe({**s, "best_is_untrained": False, "best_step": 20480,
                                        "best_validation": worse})


@pytest.mark.slow
def test_multi_seed_real(tmp_path):
    rc = cli_main(["train", "--seeds", "0-1", "--out", str(tmp_path), "--timesteps", "128", "--eval-freq", "128",
                   *TINY])
    assert rc == 0
    sums = [json.loads(open(os.path.join(tmp_path, d, "summary.json")).read()) for d in sorted(os.listdir(tmp_path))]
    assert sorted(s["seed"] for s in sums) == [0, 1]


# --- options from the Config dataclass ----------------------------------------------------------------


def test_every_config_field_is_an_option_with_its_docstring():
    """One flag per Config field (no second list), its help the field's docstring; the Launch fields on ehss train."""
    p = build_parser(argparse.ArgumentParser(), launch=True)
    actions = {a.dest: a for a in p._actions if a.dest != "help"}
    docs = options.field_docs(Config)
    assert set(actions) == {f.name for f in dataclasses.fields(Config)} | {f.name for f in dataclasses.fields(Launch)}
    for f in dataclasses.fields(Config):  # a switch that is on by default says how to turn it off
        assert docs[f.name] and docs[f.name] in actions[f.name].help, f.name
    assert "--no-progress" in actions["progress"].option_strings and "--resume" in actions["resume"].option_strings
    args = p.parse_args(["--n", "4", "--hp", "gamma=0.99", "--hp", 'env_kwargs={"agent_period": 10}',
                         "--eval-seconds", "0.5", "--no-progress"])
    cfg = config_from_args(args)
    assert cfg == Config(n=4, hp={"gamma": 0.99, "env_kwargs": {"agent_period": 10}}, eval_seconds=0.5,
                         progress=False)
    assert config_from_args(build_parser().parse_args(options.to_argv(cfg))) == cfg  # the round trip


@pytest.mark.parametrize("argv, match", [(["--n", "x"], "--n must be an integer, got 'x'"),
                                         (["--eval-seconds", "fast"], "--eval-seconds must be a number"),
                                         (["--hp", "gamma=.9x"], "--hp gamma: value '.9x' is not JSON")])
def test_bad_option_values_name_the_option(argv, match):
    with pytest.raises(runs.RunError, match=match):
        config_from_args(build_parser().parse_args(argv))


def test_run_names_are_stable(monkeypatch):
    """The names of the shipped runs follow from their settings as before (resume and the reports rely on it): with
    the recipe they were trained with (recorded in their metadata) the name is theirs."""
    from ehss_gym.agents import specs
    from ehss_gym.agents.safeweights import load_policy, shipped_models

    meta = load_policy(shipped_models()["residual-ppo-velocity-n2-seed1"]).metadata
    recorded = {**meta["agent_spec"], "net_arch": tuple(meta["agent_spec"]["net_arch"])}
    monkeypatch.setitem(specs.AGENTS, "residual-ppo", specs.AgentSpec(**recorded))
    cfg = Config(agent="residual-ppo", task="velocity", n=2, timesteps=meta["timesteps"], seed=1, eval_freq=25_000,
                 eval_episodes=16, out="elsewhere", progress=False)
    assert cfg.run_name() == meta["run_name"] == "residual-ppo_velocity_n2_s1_3b477188"


# --- the package layout ----------------------------------------------------------------------------------


@pytest.mark.parametrize("code, package", [("import agents", "ehss_gym.agents"), ("import train", "ehss_gym.train"),
                                           ("import train.loop", "ehss_gym.train")])
def test_checkout_folders_are_not_a_second_copy(code, package):
    """From the repository root, agents/ and train/ would import as top-level packages: a second copy of every
    module. That import fails with a message naming the package to import instead."""
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode != 0
    assert f"is the package {package}" in out.stderr and "second copy" in out.stderr, out.stderr[-2000:]


def test_agents_and_train_import_only_downwards():
    """Nothing in agents/ or train/ imports ehss_gym.reporting or ehss_gym.cli; agents/ does not import training."""
    for folder, banned in (("agents", ("ehss_gym.reporting", "ehss_gym.cli", "ehss_gym.train", "ehss_gym.study")),
                           ("train", ("ehss_gym.reporting", "ehss_gym.cli"))):
        for path in (ROOT / folder).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                    [node.module or ""] if isinstance(node, ast.ImportFrom) and node.level == 0 else []
                bad = [n for n in names if n.startswith(banned)]
                assert not bad, f"{path.relative_to(ROOT)}:{node.lineno} imports {bad}"


# --- the native vector env as an SB3 VecEnv ----------------------------------------------------------------

SHORT_KW = {**env_kwargs_for(get_spec("residual-ppo"), "velocity", 2), "episode_seconds": 0.05}


def _dummy(n, kw):
    return DummyVecEnv([lambda: Monitor(gym.make("EHSSTracking-v0", **kw)) for _ in range(n)])


def _same_info(a: dict, b: dict) -> None:
    assert list(a) == list(b)
    for k in a:
        if k == "terminal_observation":
            assert np.array_equal(a[k], b[k])
        elif k == "episode":
            assert (a[k]["r"], a[k]["l"]) == (b[k]["r"], b[k]["l"])
        else:
            assert str(a[k]) == str(b[k]), k  # scenario objects and metrics dicts by their text


@pytest.mark.parametrize("over, low", [({}, -1.3), ({"action": "current"}, -1.3),
                                       ({"mode": "direct", "action": "current"}, -1.3),
                                       ({"action": "current", "current_limit": None, "residual_scale": 1e5}, 0.5)])
def test_native_vec_env_steps_like_dummy_vec_env(over, low):
    """Step by step, with out-of-range actions and auto-resets every 50 steps (or at divergence): observations,
    float32 rewards, dones, infos (TimeLimit.truncated, terminal_observation, Monitor's episode, metrics,
    divergence_reason) and reset infos all equal; in the recipe's loop (its action mode, the unmodelled effects) and
    with a current residual (the last case diverges)."""
    kw = {**SHORT_KW, **over}
    a, b = _dummy(3, kw), NativeVecEnv(3, kw)
    for v in (a, b):
        v.seed(11)
    assert np.array_equal(a.reset(), b.reset())
    rng = np.random.default_rng(0)
    ends = diverged = 0
    for _ in range(160):
        act = rng.uniform(low, 1.3, size=(3, *a.action_space.shape)).astype(np.float32)
        (oa, ra, da, ia), (ob, rb, db, ib) = a.step(act), b.step(act)
        assert np.array_equal(oa, ob) and np.array_equal(ra, rb) and rb.dtype == np.float32 and np.array_equal(da, db)
        for x, y in zip(ia, ib):
            _same_info(x, y)
        ends += int(da.sum())
        diverged += sum("divergence_reason" in x for x in ib)
    for x, y in zip(a.reset_infos, b.reset_infos):
        _same_info(x, y)
    assert ends >= 6 and (diverged > 0) == ("residual_scale" in over)
    assert [g.bit_generator.state for g in a.get_attr("np_random")] == \
        [g.bit_generator.state for g in b.get_attr("np_random")]


def test_native_vec_env_trains_like_dummy_vec_env():
    """4096 agent steps of the residual-PPO recipe (8 envs, seed 3, episodes of 0.1 s so that every env restarts
    several times): the same weights, VecNormalize statistics and episode returns as with SB3's DummyVecEnv."""
    torch.set_num_threads(1)
    spec = get_spec("residual-ppo")
    kw = {**env_kwargs_for(spec, "velocity", 2), "episode_seconds": 0.1}
    models = []
    for native in (True, False):
        venv = make_env(kw, spec.n_envs, spec.gamma, spec.norm_reward, native=native)
        assert isinstance(venv.venv, NativeVecEnv if native else DummyVecEnv)
        model = make_agent(spec, venv, seed=3)
        model.learn(4096)
        models.append(model)
    a, b = (m.policy.state_dict() for m in models)
    assert all(torch.equal(a[k], b[k]) for k in a)
    va, vb = (m.get_vec_normalize_env() for m in models)
    for x, y in ((va.obs_rms.mean, vb.obs_rms.mean), (va.obs_rms.var, vb.obs_rms.var),
                 (va.ret_rms.var, vb.ret_rms.var)):
        assert np.array_equal(x, y)
    ra, rb = ([e["r"] for e in m.ep_info_buffer] for m in models)
    assert len(ra) >= 8 * 4 and ra == rb


def test_native_vec_env_attributes_and_options():
    env = NativeVecEnv(2, SHORT_KW)
    assert env.get_attr("config")[0].mode == "residual" and env.has_attr("scenario_template")
    assert not env.has_attr("no_such_attribute")
    assert env.env_is_wrapped(Monitor) == [True, True] and env.env_is_wrapped(DummyVecEnv.__base__) == [False] * 2
    g = env.get_attr("np_random", indices=[1])[0]
    env.set_attr("np_random", np.random.default_rng(5), indices=[1])
    assert env.get_attr("np_random")[1] is not g
    with pytest.raises(ValueError, match="holds all 2 sub-envs"):
        env.set_attr("render_mode", None, indices=[0])
    paper = env.get_attr("scenario_template")[0]
    env.set_options([{"scenario": "paper"}, {}])
    env.reset()
    assert env.reset_infos[0]["scenario_name"] == "paper" and env.reset_infos[1]["scenario_name"] == "random"
    env.set_options({"nope": 1})
    with pytest.raises(ValueError, match=r"reset options \['nope'\] are not supported"):
        env.reset()
    assert paper is not None
    env.close()


# --- the training report ---------------------------------------------------------------------------------


def _row(suite, policy, g, hi, failed=False, lo=None, earlier=False):
    """A harness summary row with what the targets read."""
    return {"suite": suite, "policy": policy, "figure": g, "figure_lo": lo or g * 0.9, "figure_hi": hi,
            "failed": failed, "n_failed": int(failed), "earlier_loop": earlier}


def test_a_learned_policys_standing_loses_beats_or_is_level_with_the_best_scripted_policy():
    """The training report's sentence per suite: "loses" for a G above the best scripted one's (or a failed gate),
    "beats" only where its CI's upper end is below it, else "level with" (a G at or below it, the CI holding it)."""
    from types import SimpleNamespace

    scripted = [SimpleNamespace(name="eso-n2", learned=False), SimpleNamespace(name="clf-n2", learned=False)]
    res = lambda *rows: SimpleNamespace(specs=scripted, summary=[  # noqa: E731
        _row("heldout", "eso-n2", 0.64, 0.72), _row("heldout", "clf-n2", 1.0, 1.0), *rows])
    (level,) = report_writer.standing("r", res(_row("heldout", "r", 0.64, 0.70)))
    assert level["scripted"] == "eso-n2" and not level["loses"] and not level["beats"]
    (beats,) = report_writer.standing("r", res(_row("heldout", "r", 0.50, 0.63)))
    assert beats["beats"] and not beats["loses"]
    (loses,) = report_writer.standing("r", res(_row("heldout", "r", 0.65, 0.70)))
    assert loses["loses"] and not loses["beats"]
    (failed,) = report_writer.standing("r", res(_row("heldout", "r", 0.1, 0.2, failed=True)))
    assert failed["loses"] and not failed["beats"]


def test_unmodelled_target_met_and_not_met():
    """Target (a): best learned G <= 0.80 x the best scripted G *and* its CI's upper end below the scripted G."""
    from ehss_gym.study import training as an

    scripted = [_row("unmodelled", "dcomp-n2", 0.80, 0.85), _row("unmodelled", "clf-n2", 1.0, 1.0),
                _row("heldout", "clf-n2", 1.0, 1.0)]
    learned = {"a", "b"}
    met = an.unmodelled_target(scripted + [_row("unmodelled", "a", 0.60, 0.70), _row("unmodelled", "b", 0.9, 1.0)],
                               learned)
    assert met["learned"] == "a" and met["scripted"] == "dcomp-n2" and met["met"]
    assert met["ratio"] == pytest.approx(0.75)
    # ratio 0.65/0.80 = 0.81 > 0.80: not met
    assert not an.unmodelled_target(scripted + [_row("unmodelled", "a", 0.65, 0.70)], learned)["met"]
    # ratio 0.75, but the CI reaches past the scripted figure: not met
    wide = an.unmodelled_target(scripted + [_row("unmodelled", "a", 0.60, 0.81)], learned)
    assert wide["ratio"] == pytest.approx(0.75) and not wide["met"]
    # the best learned policy is the best by the ranking order: a failed gate ranks last, and is never met
    failed = an.unmodelled_target(scripted + [_row("unmodelled", "a", 0.1, 0.2, failed=True)], learned)
    assert failed["learned"] == "a" and not failed["met"]
    assert an.unmodelled_target(scripted + [_row("unmodelled", "a", 0.1, 0.2, failed=True),
                                            _row("unmodelled", "b", 0.6, 0.7)], learned)["learned"] == "b"
    assert an.unmodelled_target(scripted, learned) is None


def test_heldout_targets_met_and_not_met():
    """Target (b): every residual-PPO group's CI upper end (clf-n2 = 1) <= 1.05, its gate passed."""
    from ehss_gym.study import training as an

    summary = [_row("heldout", "r2", 1.02, 1.05), _row("heldout", "r4", 0.98, 1.06),
               _row("heldout", "r6", 0.9, 1.0, failed=True), _row("unmodelled", "r2", 2.0, 3.0)]
    got = {d["policy"]: d for d in an.heldout_targets(summary, ["r2", "r4", "r6", "absent"])}
    assert sorted(got) == ["r2", "r4", "r6"]
    assert got["r2"]["met"] and got["r2"]["hi"] == 1.05
    assert not got["r4"]["met"] and not got["r6"]["met"]
    both = _row("heldout", "r2", 1.0, 1.01)
    both["figure_hi_both"] = 1.07  # with several seeds the CI over seeds and episodes is the one judged
    assert not an.heldout_targets([both], ["r2"])[0]["met"]


def test_validation_target_met_and_not_met():
    """Target (c): at least 4 seeds whose kept policy is a trained one (best_is_untrained false)."""
    from ehss_gym.study import training as an

    def runs(flags):
        return [{"summary": {"best_is_untrained": f, "best_step": 0 if f else 100}} for f in flags]

    assert an.validation_target(runs([False] * 4 + [True])) == {"trained": 4, "seeds": 5, "met": True}
    assert an.validation_target(runs([False] * 3 + [True] * 2)) == {"trained": 3, "seeds": 5, "met": False}


def _fake_run(root, agent, task, n, seed, model_stem=None, untrained=False):
    """A finished run folder as ehss train writes it (its kept model copied from a safe-weights stem)."""
    import shutil

    from ehss_gym.agents.specs import AGENTS

    d = root / f"{agent}_{task}_n{n}_s{seed}"
    (d / "best").mkdir(parents=True)
    spec = AGENTS[agent].as_dict()
    cfg = {"agent": agent, "task": task, "n": n, "seed": seed, "timesteps": 64, "eval_freq": 32, "eval_episodes": 1,
           "hp": {}, "agent_spec": json.loads(json.dumps(spec)), "env_kwargs": {"task": task, "n": n,
                                                                                "mode": spec["mode"]}}
    val = {"figure": 1.0 if untrained else 0.9}
    summ = {"run_name": d.name, "timesteps": 64, "wall_s": 6.0, "best_step": 0 if untrained else 64,
            "best_is_untrained": untrained, "best_validation": val, "final_validation": {"figure": 0.95}}
    hist = [{"step": 0, "figure": 1.0, "wall_s": 0.0}, {"step": 64, "figure": 0.9, "wall_s": 6.0}]
    for name, obj in (("config.json", cfg), ("summary.json", summ), ("evaluations.json", hist)):
        (d / name).write_text(json.dumps(obj))
    if model_stem is None:
        (d / "best" / "model.zip").write_bytes(b"")  # an SB3 zip (SAC): no safe weights
    else:
        for ext in (".json", ".safetensors"):
            shutil.copy(model_stem + ext, d / "best" / f"policy{ext}")
    return d


def test_ship_writes_every_group_and_retires_the_rest(tmp_path):
    """A group's trained seeds shipped as <agent>-<task>-n<n>-seed<k> (names shipped_specs groups), a seed that kept
    the untrained policy not shipped, a group with fewer than 4 trained seeds not shipped (its reason says how many),
    the models folder's other models retired, a SAC group whose zip cannot be exported skipped with its reason, the
    same weights left untouched."""
    from ehss_gym.agents.safeweights import load_policy, shipped_models
    from ehss_gym.evaluation.specs import _SEED_RE
    from ehss_gym.study import training as an

    stem = shipped_models()["residual-ppo-velocity-n2-seed0"]
    runs_dir = tmp_path / "runs"
    for seed in range(5):  # seed 2 kept the step-0 policy: 4 of 5 trained, the group ships without it
        _fake_run(runs_dir, "residual-ppo", "velocity", 2, seed, stem, untrained=seed == 2)
    for seed in range(5):  # 3 of 5 trained: the group is not shipped at all
        _fake_run(runs_dir, "residual-ppo", "velocity", 4, seed, stem, untrained=seed >= 3)
    for seed in range(4):
        _fake_run(runs_dir, "residual-sac", "velocity", 2, seed)
    models = tmp_path / "models"
    models.mkdir()
    for old in ("residual-ppo-velocity-n6-seed0", "residual-ppo-velocity-n2-seed2"):
        for ext in (".json", ".safetensors"):
            (models / (old + ext)).write_text("x")
    (models / "README.txt").write_text("kept")
    groups = an.group_runs(an.load_runs(str(runs_dir)))
    assert [an.label(k) for k in groups] == ["residual-ppo-velocity-n2", "residual-ppo-velocity-n4",
                                             "residual-sac-velocity-n2"]
    assert [an.learned_kind(rs[0]) for rs in groups.values()] == ["residual-ppo", "residual-ppo", "sb3"]
    out = an.ship(groups, str(models), made_by="test")
    names = [os.path.basename(p) for p in out.written]
    assert names == [f"residual-ppo-velocity-n2-seed{k}" for k in (0, 1, 3, 4)]
    assert {_SEED_RE.match(n).group(1) for n in names} == {"residual-ppo-velocity-n2"}
    # the untrained seed's model from an earlier shipment goes too
    assert out.retired == ["residual-ppo-velocity-n2-seed2", "residual-ppo-velocity-n6-seed0"]
    skipped = dict(out.skipped)
    assert list(skipped) == ["residual-ppo-velocity-n4", "residual-sac-velocity-n2"]
    assert "3 of its 5 seeds" in skipped["residual-ppo-velocity-n4"]  # too few trained seeds: the count named
    assert "export_saved_model" in skipped["residual-sac-velocity-n2"]  # no safe weights: the way out named
    files = sorted(n + e for n in names for e in (".json", ".safetensors"))
    assert sorted(os.listdir(models)) == ["README.txt"] + files
    assert load_policy(out.written[0]).metadata["made_by"].endswith("by test")
    stamp = os.stat(out.written[0] + ".safetensors").st_mtime_ns
    again = an.ship(groups, str(models), made_by="later")
    assert again.written == out.written and again.retired == []
    assert os.stat(out.written[0] + ".safetensors").st_mtime_ns == stamp
    # a shipment that writes nothing (only SAC) retires nothing
    only_sac = {k: v for k, v in groups.items() if k[0] == "residual-sac"}
    assert an.ship(only_sac, str(models), made_by="t").retired == [] and len(os.listdir(models)) == 9


def test_the_archive_keeps_what_the_report_reads_and_reads_back_as_the_runs(tmp_path):
    """An archived run holds its config, summary, validation history and kept model only (safe weights, or an SB3
    run's zip, statistics and settings), loads back as the same runs and groups, is left as it is when archived again,
    and two runs of one name are refused with both named."""
    from ehss_gym.agents.safeweights import shipped_models
    from ehss_gym.study import training as an

    stem = shipped_models()["residual-ppo-velocity-n2-seed0"]
    runs_dir = tmp_path / "runs"
    for seed in range(2):
        d = _fake_run(runs_dir, "residual-ppo", "velocity", 2, seed, stem)
        (d / "checkpoints").mkdir()
        (d / "checkpoints" / "step_64.zip").write_bytes(b"big")  # not read by the report: not kept
        (d / "best" / "model.zip").write_bytes(b"zip")  # the SB3 copy beside the safe weights: not kept either
    sac = _fake_run(runs_dir, "residual-sac", "velocity", 2, 0)
    for f in ("vecnormalize.pkl", "model.json"):
        (sac / "best" / f).write_bytes(b"x")
    groups = an.group_runs(an.load_runs(str(runs_dir)))
    written = an.archive(groups, str(tmp_path / "kept"))
    assert sorted(os.path.basename(w) for w in written) == sorted(os.listdir(runs_dir))

    def files(d):
        return sorted(os.path.relpath(os.path.join(r, f), d) for r, _, fs in os.walk(d) for f in fs)

    ppo = os.path.join(tmp_path, "kept", "residual-ppo_velocity_n2_s0")
    assert files(ppo) == ["best/policy.json", "best/policy.safetensors", "config.json", "evaluations.json",
                          "summary.json"]
    assert files(os.path.join(tmp_path, "kept", sac.name)) == [
        "best/model.json", "best/model.zip", "best/vecnormalize.pkl", "config.json", "evaluations.json",
        "summary.json"]
    again = an.group_runs(an.load_runs(str(tmp_path / "kept")))
    assert list(again) == list(groups)
    for k in groups:
        for a, b in zip(groups[k], again[k]):
            assert (a["config"], a["summary"], a["history"]) == (b["config"], b["summary"], b["history"])
            assert an.record_files(a) == an.record_files(b)
            for rel in an.record_files(a):
                assert (pathlib.Path(a["dir"]) / rel).read_bytes() == (pathlib.Path(b["dir"]) / rel).read_bytes(), rel
    stamp = os.stat(os.path.join(ppo, "config.json")).st_mtime_ns
    an.archive(groups, str(tmp_path / "kept"))
    assert os.stat(os.path.join(ppo, "config.json")).st_mtime_ns == stamp
    other = tmp_path / "other"
    _fake_run(other, "residual-ppo", "velocity", 4, 0, stem).rename(other / "residual-ppo_velocity_n2_s0")
    both = an.group_runs(an.load_runs(str(runs_dir)) + an.load_runs(str(other)))
    with pytest.raises(ValueError, match="two runs are named 'residual-ppo_velocity_n2_s0'"):
        an.archive(both, str(tmp_path / "clash"))


def test_an_old_sac_run_is_exported_evaluated_and_shipped_as_safe_weights(tmp_path, monkeypatch):
    """A SAC run trained before SAC runs wrote safe weights (best/model.zip + vecnormalize.pkl + model.json only) is
    scored as its zip and not shipped, the reason naming the export; exported to best/policy, its actions are the SB3
    model's, scored through the safe weights
    (the residual kind) and shipped as residual-sac-<task>-n<n>-seed<k>, which the shipped specs name
    residual-sac-<task>-n<n>."""
    import pickle

    from ehss_gym.agents import safeweights as sw
    from ehss_gym.agents.export import export_saved_model
    from ehss_gym.agents.specs import AGENTS, resolved_env_kwargs
    from ehss_gym.evaluation.specs import shipped_specs
    from ehss_gym.study import training as an
    from ehss_gym.train.loop import make_env

    runs_dir = tmp_path / "runs"
    d = _fake_run(runs_dir, "residual-sac", "velocity", 2, 0)
    kw = resolved_env_kwargs(env_kwargs_for(AGENTS["residual-sac"], "velocity", 2))
    venv = make_env(kw, 2, 0.99, False)
    venv.obs_rms.update(np.random.default_rng(0).normal(size=(50, *venv.observation_space.shape)) * 3 + 1)
    model = make_agent(AGENTS["residual-sac"], venv, seed=0)
    with torch.no_grad():  # a mean layer that acts (the zero-initialised one would hide a wrong export)
        model.policy.actor.mu.weight.normal_()
    model.save(str(d / "best" / "model.zip"))
    with open(d / "best" / "vecnormalize.pkl", "wb") as f:
        pickle.dump(venv, f)
    (d / "best" / "model.json").write_text(json.dumps({"env_kwargs": kw}))
    monkeypatch.setattr(an, "TARGET_TRAINED_SEEDS", 1)  # one seed here: the seed-count rule has its own test
    groups = an.group_runs(an.load_runs(str(runs_dir)))  # as it is: scored as its zip, not shipped
    assert an.learned_kind(next(iter(groups.values()))[0]) == "sb3"
    out = an.ship(groups, str(tmp_path / "none"), made_by="test")
    assert out.written == [] and "export_saved_model" in out.skipped[0][1]
    export_saved_model(str(d / "best"), algo="sac", name="r", metadata={})  # what the skip reason says to run
    groups = an.group_runs(an.load_runs(str(runs_dir)))
    (k, rs), = groups.items()
    assert an.kept_model(rs[0]) == str(d / "best" / "policy")
    assert an.learned_kind(rs[0]) == "residual-ppo"
    assert an.group_spec(k, rs).name == "residual-sac-velocity-n2"
    pol = sw.load_policy(str(d / "best" / "policy"))
    obs = np.random.default_rng(1).normal(size=(200, *venv.observation_space.shape)).astype(np.float32) * 3
    assert pol.head == "squashed"
    assert np.array_equal(pol.predict(obs)[0], model.predict(venv.normalize_obs(obs), deterministic=True)[0])
    models = tmp_path / "models"
    out = an.ship(groups, str(models), made_by="test")
    assert [os.path.basename(p) for p in out.written] == ["residual-sac-velocity-n2-seed0"] and out.skipped == []
    monkeypatch.setattr(sw, "MODELS_DIR", str(models))
    (spec,) = shipped_specs()
    assert (spec.name, spec.kind, spec.env_kwargs["mode"]) == ("residual-sac-velocity-n2", "residual-ppo", "residual")


def test_runs_with_todays_settings_form_one_group_however_given(tmp_path):
    """A run whose --hp overrides give today's recipe is today's group (no variant); other settings are a variant."""
    from ehss_gym.study import training as an

    stem = __import__("ehss_gym.agents.safeweights", fromlist=["x"]).shipped_models()["residual-ppo-velocity-n2-seed0"]
    d = _fake_run(tmp_path, "residual-ppo", "velocity", 2, 0, stem)
    cfg = json.loads((d / "config.json").read_text())
    assert an.variant({**cfg, "hp": {"gamma": 0.98}}) == ""  # today's value, given as a flag
    other = {**cfg, "hp": {"gamma": 0.9}, "agent_spec": {**cfg["agent_spec"], "gamma": 0.9}}
    assert an.variant(other) == '{"gamma":0.9}'
    # settings given as their own flags (--n-envs) or an agent whose defaults changed since: what differs, by name
    flags = {**cfg, "n_envs": 32, "agent_spec": {**cfg["agent_spec"], "n_envs": 32}}
    assert an.variant(flags) == '{"n_envs":32}'
    env = dict(cfg["agent_spec"]["env_kwargs"], agent_period=5)
    assert an.variant({**cfg, "agent_spec": {**cfg["agent_spec"], "env_kwargs": env}}) == \
        '{"env_kwargs":{"agent_period":5}}'
    assert an.variant({**cfg, "agent": "gone", "agent_spec": {**cfg["agent_spec"], "n_envs": 32}}).startswith(
        "settings #")


class _ZeroAction:
    """A residual policy that always acts 0: in the schedule action, the base law itself."""

    def __init__(self, dim):
        self.dim = dim

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        return np.zeros((len(obs), self.dim), dtype=np.float32), state


def test_a_policy_trained_with_unmodelled_effects_meets_them_only_in_the_unmodelled_suite():
    """The harness pins each suite's episodes: a policy whose env draws the unmodelled effects (as the residual recipe
    trains) acts on the held-out episodes without them and on the unmodelled suite's with them, exactly the episodes
    the scripted laws get. Its zero action is the base law, so every metric equals clf-n2's on both suites; with
    the effects redrawn by its own env, the unmodelled suite's figures would differ."""
    from ehss_gym.agents.specs import AGENTS
    from ehss_gym.evaluation import harness as ev

    kw = {"mode": "residual", **AGENTS["residual-ppo"].env_kwargs, "task": "position"}
    assert kw["unmodelled_effects"] and kw["action"] == "schedule"
    spec = ev.object_spec("zero", _ZeroAction(2), env_kwargs=kw)
    cfg = ev.EvalConfig(suites=("heldout", "unmodelled"), tasks=("position",), heldout_episodes=2,
                        episode_seconds=0.5, n_boot=100)
    res = ev.evaluate([ev.scripted_spec("clf-n2"), spec], cfg, workers=1, progress=False)
    eps = {ep.episode_id: ep for ep in res.episodes}
    assert all(eps[e].physical["unmodelled"].off for e in eps if e.startswith("heldout"))
    assert not any(eps[e].physical["unmodelled"].off for e in eps if e.startswith("unmodelled"))
    rows = {(r["policy"], r["episode"]): r for r in res.rows}
    for e in eps:
        for m in ("trk_rmse", "dst_peak", "tv_u_rate", "rms_u"):
            assert rows[("zero", e)][m] == rows[("clf-n2", e)][m], (e, m)
    # ... and the effects act there: the same episode with them switched off scores otherwise
    ep = eps["unmodelled-0"]
    off = {**ep.physical, "unmodelled": eps["heldout-0"].physical["unmodelled"]}
    (m,), _ = ev.rollout(_ZeroAction(2), kw, [ev.Episode("unmodelled", "position", "x", off)])
    assert m["trk_rmse"] != rows[("zero", "unmodelled-0")]["trk_rmse"]


def _fake_study():
    """A TrainingStudy with one group and one task, the harness's results replaced by what the report reads."""
    from types import SimpleNamespace

    from ehss_gym.study import training as an

    key = ("residual-ppo", "velocity", 2, "")
    rs = [{"dir": "runs/r_s0", "config": {"agent": "residual-ppo", "task": "velocity", "n": 2, "seed": 0,
                                           "timesteps": 64, "eval_freq": 64, "eval_episodes": 1, "hp": {}},
           "summary": {"timesteps": 64, "wall_s": 6.0, "best_step": 0, "best_validation": {"figure": 1.0}},
           "history": [{"step": 0, "figure": 1.0, "wall_s": 0.6}]}]
    summary = [_row("heldout", "clf-n2", 1.0, 1.0), _row("heldout", "residual-ppo-velocity-n2", 1.02, 1.04),
               _row("unmodelled", "dcomp-n2", 0.7, 0.7), _row("unmodelled", "residual-ppo-velocity-n2", 0.9, 0.95)]
    for d in summary:
        d.update({"n_runs": 1, "n_episodes": 2, "figure_iqm": d["figure"], "trk_rmse": 1e-6, "dst_peak": 1e-4,
                  "tv_u_rate": 50.0, "rank": 1})
    specs = [SimpleNamespace(name=n, learned=n.startswith("residual")) for n in ("clf-n2", "dcomp-n2",
                                                                                  "residual-ppo-velocity-n2")]
    res = SimpleNamespace(summary=summary, comparisons=[], specs=specs)
    diag = {"suite": "heldout", "episodes": 2, "noisy_episodes": 1, "tv_rate_median_noisy": 1e4,
            "tv_rate_median_clean": 50.0, "saturation_mean": 0.1, "trk_rmse_median": 1e-6}
    task = {"task": "velocity", "wall": 12.3, "diag": [diag],
            "unmodelled": an.unmodelled_target(summary, {"residual-ppo-velocity-n2"}),
            "heldout": an.heldout_targets(summary, ["residual-ppo-velocity-n2"])}
    seeds = {key: [{"seed": 0, "run": "r_s0", "step0": 1.0, "best": 1.0, "best_step": 0, "final": 1.1,
                    "untrained": True, "heldout": 1.02, "unmodelled": 0.9, "wall_s": 6.0}]}
    shipment = an.Shipment(written=[], retired=["residual-ppo-velocity-n6-seed0"],
                           skipped=[("residual-sac-velocity-n2", "no safe weights")])
    return an.TrainingStudy({key: rs}, {"velocity": res}, [task], seeds, {key: an.validation_target(rs)}, shipment,
                            None, 8, "models")


def test_report_template_renders_every_section():
    study = _fake_study()
    text = report_writer.markdown("ehss training-report --runs r", study, None)
    for part in ("# Training: residual PPO, residual SAC and pure PPO on EHSSTracking-v0", "## Runs",
                 "## Hyperparameters", "## Learning curves and seeds", "### residual-ppo-velocity-n2",
                 "![residual-ppo-velocity-n2](curve_residual-ppo-velocity-n2.png)",
                 "**It loses on the held-out suite**: G 1.020 (95 % CI [0.918, 1.040]) against 1.000 for clf-n2",
                 "**It loses on the unmodelled suite**: G 0.900", "trained (not the step-0 one) in 0 of 1 seeds",
                 "| 0 | 1.000 | 1.000 | 0 | 1.100 | yes | 1.020 | 0.900 | 0.100 |", "## Results, velocity task",
                 "ratio 1.286 -> **NOT met**", "Unmodelled suite in at least one task: **NOT met**",
                 "`residual-ppo-velocity-n2` (CI upper end of G <= 1.05, clf-n2 = 1): G 1.020, 95 % CI [0.918, 1.040]"
                 " -> **met**", "0 of 1 -> **NOT met** (fewer than 5 seeds ran)", "Evaluation wall time: 12 s.",
                 "## Shipped models", "Nothing was shipped.",
                 "`residual-sac-velocity-n2` not shipped: no safe weights.",
                 "Retired (deleted from `models`", "`residual-ppo-velocity-n6-seed0`"):
        assert part in text, part
    assert "## Initial exploration noise" not in text and "\n\n\n" not in text
    for word in ("issue", "wave"):
        assert word not in text.lower()


def test_training_report_command_refuses_bad_input(tmp_path, capsys):
    assert cli_main(["training-report", "--runs", str(tmp_path / "none"), "--out", str(tmp_path / "out")]) == 2
    assert "ehss training-report: error: --runs folder" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert cli_main(["training-report", "--runs", str(tmp_path / "empty"), "--out", str(tmp_path / "out")]) == 2
    assert "no finished runs" in capsys.readouterr().err


def test_train_config_file_gives_defaults_that_flags_override_and_bad_files_are_named(tmp_path):
    path = tmp_path / "best_config.json"
    path.write_text(json.dumps({"agent": "residual-ppo", "n": 4, "timesteps": 4096, "hp": {"gamma": 0.95}}))
    p = build_parser(argparse.ArgumentParser(), launch=True)
    cfg = config_from_args(p.parse_args(["--config", str(path), "--timesteps", "128", "--seed", "2"]))
    assert cfg == Config(n=4, timesteps=128, seed=2, hp={"gamma": 0.95})
    path.write_text(json.dumps({"n": 4, "learning_rate": 1e-3}))
    with pytest.raises(runs.RunError, match=r"--config .*must be a JSON object of Config fields.*\['learning_rate'\]"):
        config_from_args(p.parse_args(["--config", str(path)]))
    path.write_text("{not json")
    with pytest.raises(runs.RunError, match="not JSON"):
        config_from_args(p.parse_args(["--config", str(path)]))
    with pytest.raises(runs.RunError, match="cannot read it"):
        config_from_args(p.parse_args(["--config", str(tmp_path / "missing.json")]))
    path.write_text(json.dumps({"n": 3}))
    assert cli_main(["train", "--config", str(path), "--out", str(tmp_path / "r")]) == 2  # validated like a flag


def test_report_names_the_exploration_study_by_its_command():
    """The exploration section names the command that runs the study today, says so when the JSON it reads was
    recorded under another module name, and leaves out a study of an earlier loop."""
    from ehss_gym.agents.specs import AGENTS, env_kwargs_for, resolved_env_kwargs
    from ehss_gym.study.exploration import COMMAND

    study = _fake_study()
    row = {"log_std_init": -1.0, "std_mA": 3.7, "explore_figure": 1.0, "early_figures": {"0": [1.0]},
           "mean_early_figure": 1.0, "worst_early_figure": 1.0, "below_base": False}
    kw = json.loads(json.dumps(resolved_env_kwargs(env_kwargs_for(AGENTS["residual-ppo"], "velocity", 2))))
    ex = {"command": COMMAND, "seeds": [0], "episodes": 2, "timesteps": 64, "eval_freq": 32, "rows": [row],
          "largest_safe_log_std_init": -1.0, "env_kwargs": kw}
    text = report_writer.markdown("ehss training-report --runs r", study, ex)
    assert f"Measured by `{COMMAND}` (seeds" in text
    old = report_writer.markdown("ehss training-report --runs r", study, {**ex, "command": "python -m old.name"})
    assert f"Measured by `{COMMAND}`" in old and "`python -m old.name`, which no longer exists" in old
    earlier = report_writer.markdown("ehss training-report --runs r", study,
                                     {**ex, "env_kwargs": {**kw, "action": "current"}})
    assert "## Initial exploration noise" not in earlier and "measured an earlier loop" in earlier


def test_a_seed_trains_the_same_weights_twice_and_another_seed_other_ones(tmp_path):
    """On one machine a seed's run is reproducible to the byte (docs/REPRODUCIBILITY.md); a second seed shows the
    comparison can see a difference."""
    def weights(name: str, seed: int) -> bytes:
        out = str(tmp_path / name)
        assert cli_main(["train", "--timesteps", "256", "--eval-freq", "128", "--seed", str(seed), "--out", out,
                         *TINY]) == 0
        with open(os.path.join(out, "final", "policy.safetensors"), "rb") as f:
            return f.read()

    first = weights("a", 0)
    assert weights("b", 0) == first and weights("c", 1) != first


def test_the_reports_train_command_carries_the_runs_settings():
    """A group's command in the training report repeats every setting its runs were given beyond the usual ones
    (--n-envs, --plant, --law-settings, --hp), so that it trains the same runs again; runs without them get none."""
    from ehss_gym.reporting.training import runs_context

    base = {"agent": "residual-ppo", "task": "velocity", "n": 2, "seed": 0, "timesteps": 64, "eval_freq": 32,
            "eval_episodes": 1, "hp": {}, "n_envs": None}
    given = {**base, "n_envs": 32, "plant": "compact140", "hp": {"gamma": 0.99}}
    (plain,) = runs_context({("residual-ppo", "velocity", 2, ""): [{"config": base}]})
    (rich,) = runs_context({("residual-ppo", "velocity", 2, "x"): [{"config": given}]})
    assert plain["hp"] == ""
    assert rich["hp"] == " --n-envs 32 --plant compact140 --hp 'gamma=0.99'"
