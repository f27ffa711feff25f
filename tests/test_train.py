"""Training: config and seed parsing, run names, the CLI's bad-input errors, a smoke run, resume after kill -9."""

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from ehss_gym.train import runs
from ehss_gym.train.loop import Config

from ehss_gym.cli import main as cli_main

# A tiny but complete run: 2 envs x 64 steps per rollout, 1 validation episode.
TINY = ["--n-envs", "2", "--hp", "n_steps=64", "--hp", "batch_size=64", "--hp", "n_epochs=1", "--eval-episodes", "1",
        "--eval-seconds", "0.1", "--no-progress"]


# --- seeds, names ----------------------------------------------------------------------------------


def test_parse_seeds_forms():
    assert runs.parse_seeds("3") == [3]
    assert runs.parse_seeds("0-4") == [0, 1, 2, 3, 4]
    assert runs.parse_seeds("0-2, 7,2") == [0, 1, 2, 7]


@pytest.mark.parametrize("text, match", [("4-0", "start > end"), ("a", "bad item 'a'"), ("", "must be like"),
                                         ("-1", "bad item '-1'"), ("1-", "bad item '1-'"),
                                         ("0-10000", r"integers in \[0, 10000\)"), ("1,,2", "bad item ''")])
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
    (["--agent", "sac"], r"--agent must be one of \['ppo', 'residual-ppo'\], got 'sac'"),
    (["--seeds", "4-0"], "--seeds range '4-0' has start > end"),
    (["--seeds", "x"], "--seeds must be like"),
    (["--seed", "1", "--seeds", "0-1"], "either --seed or --seeds"),
    (["--n", "3"], "--n must be an even integer >= 2"),
    (["--task", "torque"], "--task must be one of"),
    (["--timesteps", "0"], "--timesteps must be an integer >= 1"),
    (["--hp", "gamma"], "--hp must be KEY=JSON"),
    (["--hp", "nope=1"], r"unknown or fixed agent hyperparameter\(s\) \['nope'\]"),
    (["--jobs", "0", "--seeds", "0-1"], "--jobs must be an integer >= 1"),
    (["--eval-seconds", "0"], r"--eval-seconds must be a number in \[0.01, 100\]"),
])
def test_cli_bad_input_exit_2(argv, match, capsys, tmp_path):
    assert cli_main(["train", "--out", str(tmp_path / "r"), *argv]) == 2
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

    import torch

    g = [np.random.default_rng(5), np.random.default_rng(6)]
    st = json.loads(json.dumps(runs.capture_rng(g)))  # survives JSON
    want = (random.random(), np.random.rand(), torch.rand(1).item(), g[0].random(), g[1].random())
    random.random(), np.random.rand(), torch.rand(1), g[0].random(), g[1].random()  # move on
    runs.restore_rng(st, g)
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

    from ehss_gym.agents.safeweights import load_policy
    from ehss_gym.agents.specs import resolved_env_kwargs
    from stable_baselines3 import PPO

    from ehss_gym.envs import EHSSTrackingEnv

    out = tmp_path / "run"
    rc = cli_main(["train", "--timesteps", "256", "--eval-freq", "128", "--checkpoint-freq", "128", "--out", str(out),
                   *TINY])
    assert rc == 0
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["agent_spec"]["n_steps"] == 64 and cfg["env_kwargs"]["mode"] == "residual"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["timesteps"] == 256 and summary["wall_s"] > 0
    hist = json.loads((out / "evaluations.json").read_text())
    assert [r["step"] for r in hist] == [0, 128, 256]
    assert hist[0]["rel_rmse"] == 1.0 and hist[0]["rel_tv"] == 1.0  # step 0 is exactly the base law
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
    from ehss_gym.train import analysis as report

    groups = report.group_runs(report.load_runs(str(tmp_path)))
    assert [k[:3] for k in groups] == [("residual-ppo", "velocity", 2)]
    assert json.loads(list(groups)[0][3]) == {"batch_size": 64, "n_epochs": 1, "n_steps": 64}  # the --hp variant
    report.plot_curves(groups, str(tmp_path / "curves.png"))
    assert (tmp_path / "curves.png").stat().st_size > 1000
    shipped = report.ship(groups, str(tmp_path / "models"))
    assert [os.path.basename(p) for p in shipped] == ["residual-ppo-velocity-n2-seed0"]
    ship_pol = load_policy(shipped[0])
    assert ship_pol.name == "residual-ppo-velocity-n2-seed0"
    best = load_policy(str(out / "best" / "policy"))
    assert np.array_equal(ship_pol.predict(obs)[0], best.predict(obs)[0])


def test_training_other_base_law(tmp_path):
    """n = 4: the score's reference is still the n = 2 law on the same episodes."""
    out = tmp_path / "n4"
    assert cli_main(["train", "--n", "4", "--timesteps", "128", "--eval-freq", "128", "--out", str(out), *TINY]) == 0
    s = json.loads((out / "summary.json").read_text())
    assert s["n"] == 4 and s["base_validation"]["rel_rmse"] == 1.0
    assert s["base_validation"]["score"] != 1.0  # the n = 4 law against the n = 2 reference


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


def test_multi_seed_launches_one_process_per_seed(tmp_path, monkeypatch, capsys):
    """--seeds starts one child per seed, at most --jobs at a time (children faked here; see the slow test)."""
    import ehss_gym.cli.train as tc

    started, alive = [], []

    class Fake:
        def __init__(self, argv, **kw):
            started.append(argv)
            alive.append(self)
            assert len(alive) <= 2
            self.polls = 0

        def poll(self):
            self.polls += 1
            if self.polls < 2:
                return None
            if self in alive:
                alive.remove(self)
            return 0

        def kill(self):
            raise AssertionError("no child should be left to kill")

    monkeypatch.setattr(tc.subprocess, "Popen", Fake)
    monkeypatch.setattr(tc.time, "sleep", lambda s: None)
    assert cli_main(["train", "--seeds", "0-2", "--jobs", "2", "--out", str(tmp_path), "--timesteps", "64",
                     *TINY]) == 0
    seeds = [a[a.index("--seed") + 1] for a in started]
    assert seeds == ["0", "1", "2"]
    outs = [a[a.index("--out") + 1] for a in started]
    assert len(set(outs)) == 3 and all(os.path.dirname(o) == str(tmp_path) for o in outs)
    tiny = dict(n_envs=2, eval_episodes=1, eval_seconds=0.1, hp={"n_steps": 64, "batch_size": 64, "n_epochs": 1})
    assert all(os.path.basename(o) == Config(seed=int(s), **tiny).run_name() for o, s in zip(outs, seeds))
    assert all("--hp" in a and "--no-progress" in a for a in started)


@pytest.mark.slow
def test_multi_seed_real(tmp_path):
    rc = cli_main(["train", "--seeds", "0-1", "--out", str(tmp_path), "--timesteps", "128", "--eval-freq", "128",
                   *TINY])
    assert rc == 0
    sums = [json.loads(open(os.path.join(tmp_path, d, "summary.json")).read()) for d in sorted(os.listdir(tmp_path))]
    assert sorted(s["seed"] for s in sums) == [0, 1]


def test_period_log_replays_the_agents_loop_at_the_control_rate():
    """The report's TV decomposition logs every control period by re-running a policy at agent_period 1; that
    loop must be the one the policy acts in (same metrics as at its own agent period), and its TV count
    complete (equal to the metrics' TV)."""
    from ehss_gym.agents.safeweights import load_policy, shipped_models
    from ehss_gym.train.analysis import has_noise, period_log

    from ehss_gym.core.scenarios import heldout_scenarios

    pol = load_policy(shipped_models()["residual-ppo-velocity-n2-seed1"])  # a seed whose kept policy acts (as on main)
    tmpl = pol.make_env().unwrapped.scenario_template
    sc = next(s for s in heldout_scenarios(48, tmpl) if has_noise(s.noise_std)).replace(t_end=0.2)
    env = pol.make_env()
    obs, _ = env.reset(options={"scenario": sc})
    while True:
        obs, _, term, trunc, info = env.step(pol.predict(obs)[0])
        if term or trunc:
            break
    log = period_log(pol, sc)
    assert log["rmse"] == info["metrics"]["rmse"] and log["metrics_tv"] == info["metrics"]["tv_u"]
    assert log["tv"] == pytest.approx(log["metrics_tv"], rel=1e-9) and log["tv_own"] > 0 and log["crossings"] > 0
    base = period_log(pol, sc, base_only=True)
    assert base["tv_own"] == 0.0 and base["rmse"] != log["rmse"]
