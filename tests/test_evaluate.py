"""The evaluation harness: policy specs and their errors, scores, ranking, determinism, loading and the CLI."""

import ast
import csv
import json
import math
import os
import pathlib
from dataclasses import replace

import numpy as np
import pytest
from gymnasium import spaces
from stable_baselines3 import PPO

from ehss_gym import __version__
from ehss_gym import evaluation as ev
from ehss_gym.cli import main
from ehss_gym.core.scenarios import HELDOUT_SEED_BASE, TRAIN_SEED_LIMIT
from ehss_gym.envs import EHSSTrackingEnv
from ehss_gym.evaluation import harness, loading
from ehss_gym.reporting import comparison

try:  # the agents restructuring moves the exporter out of safeweights (which then needs no torch)
    from ehss_gym.agents.export import export_policy
except ImportError:
    from ehss_gym.agents.safeweights import export_policy

# a small, cheap configuration: held-out episodes of 0.3 s on the velocity task
TINY = ev.EvalConfig(suites=("heldout",), tasks=("velocity",), heldout_episodes=3, episode_seconds=0.3, n_boot=200)


def _csv_rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


# ---------------------------------------------------------------------------------------------------
# Scores


def test_primary_score_definition():
    assert ev.primary_score(0.01, 100.0, 0.01, 100.0, False) == pytest.approx(1.0)
    # half the error at the same chattering: 0.5 * 0.5 + 0.5 * 1
    assert ev.primary_score(0.005, 100.0, 0.01, 100.0, False) == pytest.approx(0.75)
    assert ev.primary_score(0.01, 0.0, 0.01, 100.0, False) == pytest.approx(0.5)
    assert ev.primary_score(0.01, 100.0, 0.01, 100.0, True) == ev.SCORE_CAP
    assert ev.primary_score(1.0, 1e9, 0.01, 100.0, False) == ev.SCORE_CAP
    assert ev.primary_score(math.nan, 1.0, 0.01, 100.0, False) == ev.SCORE_CAP


# ---------------------------------------------------------------------------------------------------
# Policy specs and bad input


def test_parse_scripted_and_unknown_names():
    s = ev.parse_policy("clf-n6")
    assert s.kind == "clf" and s.env_kwargs["n"] == 6 and s.tasks == ("velocity", "position")
    assert ev.parse_policy("pid").env_kwargs["mode"] == "direct"
    with pytest.raises(ev.PolicyError, match=r"unknown policy 'clf-n3'.*even integer"):
        ev.parse_policy("clf-n3")
    with pytest.raises(ev.PolicyError, match=r"unknown policy 'sac'; valid: clf-n<even n >= 2>.*pid.*residual-ppo:"):
        ev.parse_policy("sac")
    with pytest.raises(ev.PolicyError, match=r"unknown policy kind 'dqn'"):
        ev.parse_policy("dqn:model.zip")
    with pytest.raises(ev.PolicyError, match="needs a PATH"):
        ev.parse_policy("residual-ppo:")


def test_missing_model_file(tmp_path):
    missing = str(tmp_path / "nope")
    with pytest.raises(ev.PolicyError, match=r"'residual-ppo:.*nope'.*file not found.*safetensors \+ PATH.json"):
        ev.parse_policy(f"residual-ppo:{missing}")
    with pytest.raises(ev.PolicyError, match="no file matches the pattern"):
        ev.parse_policy(f"ppo-direct:{tmp_path}/run_*.zip")


@pytest.mark.parametrize("argv, needle", [
    (["--policies", "sac"], "unknown policy 'sac'"),
    (["--policies", "clf-n2,clf-n5"], "clf-n5"),
    (["--policies", "residual-ppo:/no/such/model"], "file not found '/no/such/model'"),
    (["--policies", "ppo-direct:/no/such/model.zip"], "/no/such/model.zip"),
])
def test_cli_bad_policy_exit_2(argv, needle, capsys, tmp_path):
    rc = main(["evaluate", *argv, "--out", str(tmp_path / "out"), "--store", str(tmp_path / "jobs"), "--no-progress"])
    assert rc == 2
    err = capsys.readouterr().err
    assert needle in err and "error" in err
    assert not (tmp_path / "out" / "REPORT.md").exists()


@pytest.mark.parametrize("argv", [["--episodes", "0"], ["--suite", "bogus"], ["--task", "velocity,torque"],
                                  ["--n-boot", "10"], ["--workers", "0"]])
def test_cli_bad_options_exit_2(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["evaluate", *argv])
    assert exc.value.code == 2
    assert "error" in capsys.readouterr().err


class _FixedPolicy:
    """An object with SB3's predict returning a constant action of a given shape."""

    def __init__(self, obs_dim=15, act_dim=1, value=0.0):
        self.observation_space = spaces.Box(-10, 10, (obs_dim,), np.float32)
        self.action_space = spaces.Box(-1, 1, (act_dim,), np.float32)
        self.value = value

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        obs = np.asarray(observation)
        return np.full((obs.shape[0], self.action_space.shape[0]), self.value, np.float32), state


def test_shape_mismatch_names_what_fits():
    bad_obs = ev.object_spec("wrong-obs", _FixedPolicy(obs_dim=17), env_kwargs={"task": "velocity"})
    with pytest.raises(ev.PolicyError) as exc:
        ev.evaluate([bad_obs], TINY, workers=1, progress=False)
    msg = str(exc.value)
    assert "'wrong-obs'" in msg and "(17,)" in msg and "(15,)" in msg and "task='position': observation (17,)" in msg
    bad_act = ev.object_spec("wrong-act", _FixedPolicy(act_dim=2), env_kwargs={"task": "velocity"})
    with pytest.raises(ev.PolicyError, match=r"'wrong-act'.*actions of shape \(2,\).*action shape \(1,\)"):
        ev.evaluate([bad_act], TINY, workers=1, progress=False)
    with pytest.raises(ev.PolicyError, match="has no predict"):
        ev.object_spec("no-predict", object())


def _ppo(task="velocity", mode="residual"):
    env = EHSSTrackingEnv(task=task, mode=mode)
    return PPO("MlpPolicy", env, n_steps=64, batch_size=32, seed=0, device="cpu",
               policy_kwargs={"net_arch": [16, 16]})


def test_sb3_zip_and_safe_weights_are_evaluated(tmp_path, capsys):
    model = _ppo()
    zip_path = str(tmp_path / "res_seed0.zip")
    model.save(zip_path)
    export_policy(model, tmp_path / "safe-seed0", env_kwargs={"task": "velocity", "mode": "residual"})
    export_policy(_ppo(), tmp_path / "safe-seed1", env_kwargs={"task": "velocity", "mode": "residual"})
    zspec = ev.parse_policy(f"residual-ppo:{zip_path}")
    assert zspec.runs == [zip_path] and zspec.tasks == ("velocity",)
    multi = ev.parse_policy(f"residual-ppo:{tmp_path}/safe-seed*")
    assert len(multi.runs) == 2 and multi.name == "residual-ppo:safe"
    with pytest.raises(ev.PolicyError, match=r"mode='residual'; name it residual-ppo:"):
        ev.parse_policy(f"ppo-direct:{tmp_path}/safe-seed0")
    res = ev.evaluate([ev.parse_policy("clf-n2"), zspec, multi], TINY, workers=1, progress=False)
    by = {d["policy"]: d for d in res.summary}
    assert by[zspec.name]["n_runs"] == 1 and by[multi.name]["n_runs"] == 2
    assert "score_mean_lo_seeds" in by[multi.name]  # a CI over training seeds exists with 2 seeds
    assert {c["policy"] for c in res.comparisons} == {zspec.name, multi.name}
    for d in by.values():
        assert d["n_episodes"] == 3 and math.isfinite(d["score_mean"])


def test_corrupt_or_tampered_model_exit_2(tmp_path, capsys):
    bad_zip = tmp_path / "broken.zip"
    bad_zip.write_bytes(b"not a zip")
    argv = ["--suite", "heldout", "--task", "velocity", "--episodes", "1", "--out", str(tmp_path / "o"),
            "--store", str(tmp_path / "jobs"), "--no-progress"]
    assert main(["evaluate", "--policies", f"residual-ppo:{bad_zip}", *argv]) == 2
    err = capsys.readouterr().err
    assert "'residual-ppo:broken (sb3 zip)'" in err and "not a loadable stable-baselines3 model" in err
    st_path, _ = export_policy(_ppo(), tmp_path / "tampered", env_kwargs={"task": "velocity", "mode": "residual"})
    blob = bytearray(open(st_path, "rb").read())
    blob[-1] ^= 0x01
    open(st_path, "wb").write(bytes(blob))
    assert main(["evaluate", "--policies", f"residual-ppo:{tmp_path}/tampered", *argv]) == 2
    assert "SHA-256" in capsys.readouterr().err


def test_safe_weights_shape_mismatch_cli(tmp_path, capsys):
    # trained on the position task (17 observations) but labelled velocity (15)
    export_policy(_ppo(task="position"), tmp_path / "mislabelled", env_kwargs={"task": "velocity", "mode": "residual"})
    rc = main(["evaluate", "--policies", f"residual-ppo:{tmp_path}/mislabelled", "--suite", "heldout", "--task",
               "velocity", "--episodes", "1", "--out", str(tmp_path / "out"), "--store", str(tmp_path / "jobs"),
               "--no-progress"])
    assert rc == 2
    err = capsys.readouterr().err
    assert "mislabelled" in err and "(17,)" in err and "(15,)" in err and "What fits" in err


def test_learned_policy_is_compared_with_clf_at_its_settings():
    # a "learned" residual policy trained at sigma = 1e4: the CLF laws at sigma = 1e4 are added for it
    spec = ev.object_spec("zero-residual", _FixedPolicy(value=0.0), env_kwargs={"task": "velocity", "sigma": 1e4})
    res = ev.evaluate([ev.parse_policy("clf-n2"), spec], TINY, workers=1, progress=False)
    names = {s.name for s in res.specs}
    assert {"clf-n2@sigma=10000", "clf-n4@sigma=10000", "clf-n6@sigma=10000"} <= names
    (c,) = res.comparisons
    assert c["best_clf"].endswith("@sigma=10000") and c["base_law"] == "clf-n2@sigma=10000"
    # a zero residual is exactly its base law: same episodes, same numbers
    assert c["rmse_ratio"] == pytest.approx(1.0, abs=1e-12) and c["tv_ratio"] == pytest.approx(1.0, abs=1e-12)
    rows = {(r["policy"], r["episode"]): r for r in res.rows}
    for i in range(TINY.heldout_episodes):
        assert rows[("zero-residual", f"heldout-{i}")]["score"] == rows[("clf-n2@sigma=10000", f"heldout-{i}")]["score"]
    # the comparison's scores are normalised by the n = 2 law at the policy's settings, so the zero residual
    # (that very law) scores exactly 1 there, whatever the default reference law does on those episodes
    assert c["score_reference"] == "clf-n2@sigma=10000" and c["score_mean"] == pytest.approx(1.0, abs=1e-12)
    assert rows[("zero-residual", "heldout-0")]["score"] != pytest.approx(1.0)  # against clf-n2 at the defaults


# ---------------------------------------------------------------------------------------------------
# Suites, ranking and determinism


def test_episodes_are_disjoint_from_training_and_fixed():
    cfg = ev.EvalConfig.quick()
    a = ev.build_episodes(cfg)
    b = ev.build_episodes(cfg)
    assert [e.episode_id for e in a] == [e.episode_id for e in b]
    def canon(ep):
        return {k: (v.to_dict() if hasattr(v, "to_dict") else v) for k, v in ep.physical.items()}

    assert all(canon(x) == canon(y) for x, y in zip(a, b))
    held = [e for e in a if e.suite != "paper"]
    assert held and all(e.scenario_seed >= HELDOUT_SEED_BASE >= TRAIN_SEED_LIMIT for e in held)
    sweep = [e for e in a if e.suite == "robustness" and e.sweep == "friction" and e.level == 3.6]
    assert all(e.physical["friction"] == ((3.6,) + ev.SWEEP_WINDOW,) for e in sweep)
    mis = [e for e in a if e.suite == "robustness" and e.sweep == "mismatch" and e.level == 0.2]
    assert all(e.physical["plant"] != e.physical["model"] for e in mis)


def test_harness_ranks_a_badly_tuned_law_last():
    """A PID with a far too small proportional gain (and no I or D) must rank below the CLF laws."""
    cfg = ev.EvalConfig(suites=("heldout",), tasks=("velocity",), heldout_episodes=8, episode_seconds=0.5,
                        n_boot=1000)
    detuned = ev.scripted_spec("pid", label="pid-detuned", gains={"velocity": (0.01, 0.0, 0.0)})  # mA per rad/s
    specs = [ev.parse_policy("clf-n2"), ev.parse_policy("clf-n4"), detuned]
    res = ev.evaluate(specs, cfg, workers=1, progress=False)
    block = {d["policy"]: d for d in res.summary}
    assert block["pid-detuned"]["rank"] == 3
    assert {block["clf-n2"]["rank"], block["clf-n4"]["rank"]} == {1, 2}
    worst_good_hi = max(block[n]["score_mean_hi"] for n in ("clf-n2", "clf-n4"))
    assert block["pid-detuned"]["score_mean_lo"] > worst_good_hi  # non-overlapping 95 % CIs
    assert block["pid-detuned"]["score_iqm_lo"] > max(block[n]["score_iqm_hi"] for n in ("clf-n2", "clf-n4"))
    assert block["pid-detuned"]["poi_hi"] < 0.5  # it (almost) never beats the best CLF
    assert block["pid-detuned"]["rmse"] > 3 * block["clf-n2"]["rmse"]


def test_results_do_not_depend_on_workers():
    specs = [ev.parse_policy("clf-n2"), ev.object_spec("const", _FixedPolicy(value=0.05),
                                                        env_kwargs={"task": "velocity"})]
    one = ev.evaluate(specs, TINY, workers=1, progress=False)
    two = ev.evaluate(specs, TINY, workers=2, progress=False)
    assert two.workers == 2
    key = ("policy", "episode", "score", "rmse", "tv_u_rate", "max_abs_e")
    assert [tuple(r[k] for k in key) for r in one.rows] == [tuple(r[k] for k in key) for r in two.rows]
    # the constant residual changed the outcome (the policy's action reaches the plant)
    r = {(x["policy"], x["episode"]): x for x in one.rows}
    assert any(r[("const", e)]["rmse"] != r[("clf-n2", e)]["rmse"] for e in ("heldout-0", "heldout-1"))


def test_a_law_evaluated_on_both_tasks_acts_on_each_with_its_own_object():
    """A scripted law's item (its description) is the same for both tasks; the object made from it is not: a worker
    that ran the velocity episodes first must not score the position ones with the velocity PID (it did, at
    first, under the execution layer's cache)."""
    key = ("task", "episode", "score", "rmse", "tv_u_rate")
    for workers in (1, 2):
        mixed = ev.evaluate([ev.parse_policy("pid")], replace(TINY, tasks=("velocity", "position")), workers=workers,
                            progress=False)
        alone = ev.evaluate([ev.parse_policy("pid")], replace(TINY, tasks=("position",)), workers=workers,
                            progress=False)
        pos = [tuple(r[k] for k in key) for r in mixed.rows if r["task"] == "position" and r["policy"] == "pid"]
        assert pos and pos == [tuple(r[k] for k in key) for r in alone.rows if r["policy"] == "pid"]


# ---------------------------------------------------------------------------------------------------
# The CLI end to end (--quick is what CI runs)


def test_cli_quick_writes_the_report(tmp_path, capsys):
    out = tmp_path / "cmp"
    rc = main(["evaluate", "--quick", "--out", str(out), "--store", str(tmp_path / "jobs"), "--no-progress"])
    assert rc == 0
    for f in ("REPORT.md", "episodes.csv", "summary.csv", "figures/scores_heldout.png", "figures/scores_paper.png",
              "figures/paper_traces_velocity.png", "figures/paper_traces_position.png",
              "figures/robustness_velocity.png", "figures/metrics_heldout_velocity.png"):
        assert (out / f).is_file(), f
    text = (out / "REPORT.md").read_text()
    assert "`ehss evaluate" in text and "--quick" in text and f"ehss-gym {__version__}" in text
    assert "score = 0.5 * RMSE / RMSE_ref + 0.5 * TV / TV_ref" in text
    for label in ("RMSE", "IAE", "ITAE", "recovery on", "control TV", "saturation", "divergence rate", "V decrease"):
        assert label in text
    cfg = ev.EvalConfig.quick()
    n_specs = len(ev.default_specs())
    rows = _csv_rows(out / "episodes.csv")
    per_task = 1 + cfg.heldout_episodes + cfg.sweep_episodes * (len(cfg.friction_levels) + len(cfg.mismatch_levels))
    scripted = len(ev.SCRIPTED_DEFAULT)
    assert len(rows) >= scripted * 2 * per_task
    assert len(rows) <= n_specs * 2 * per_task * 10  # learned models add at most a few seeds per task
    ref = [r for r in rows if r["policy"] == ev.REFERENCE_POLICY]
    assert all(float(r["score"]) == pytest.approx(1.0) for r in ref)
    summary = _csv_rows(out / "summary.csv")
    assert {r["suite"] for r in summary} == {"paper", "heldout", "robustness"}
    assert not [p for p in os.listdir(out) if p.startswith(".tmp-")]  # no temp files left behind


def test_interrupted_run_keeps_previous_report(tmp_path, monkeypatch):
    res = ev.evaluate([ev.parse_policy("clf-n2")], TINY, workers=1, progress=False)
    out = tmp_path / "cmp"
    comparison.write_report(res, str(out))
    before = (out / "REPORT.md").read_text()
    assert "**No learned policy was evaluated**" in before and "\n\n\n" not in before
    assert "## 9. Learned policies against the scripted laws\n\nNo learned policy was evaluated, so" in before

    def boom(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(comparison, "report_text", boom)
    res.command = "ehss evaluate --changed"
    with pytest.raises(KeyboardInterrupt):
        comparison.write_report(res, str(out))
    assert (out / "REPORT.md").read_text() == before
    assert not [p for p in os.listdir(out) if p.startswith(".tmp-")]
    json.dumps(res.summary, default=str)  # summaries are plain data


# ---------------------------------------------------------------------------------------------------
# Loading once, layering and the names other layers use


def test_each_model_is_loaded_once(tmp_path, monkeypatch):
    for k in range(2):
        export_policy(_ppo(), tmp_path / f"once-seed{k}", env_kwargs={"task": "velocity", "mode": "residual"})
    calls = []
    real = loading.load_policy

    def counting(path):
        calls.append(str(path))
        return real(path)

    monkeypatch.setattr(loading, "load_policy", counting)
    spec = ev.parse_policy(f"residual-ppo:{tmp_path}/once-seed*")
    ev.evaluate([ev.parse_policy("clf-n2"), spec], TINY, workers=1, progress=False)
    # parsing, the shape check and the episodes share a load
    assert sorted(os.path.basename(c) for c in calls) == ["once-seed0", "once-seed1"]
    # worker processes (local or on other machines) get a safe-weights model as the bytes of its two files, not a
    # pickle, and rebuild it through the safe-weights loader from a private copy, never reading the model's files
    pol = loading.load_run(spec.runs[0], "velocity", spec.env_kwargs_for("velocity"))
    item = loading.portable(spec.runs[0], pol)
    assert item[0] == "safe" and item[1]["safetensors"] == (tmp_path / "once-seed0.safetensors").read_bytes()
    assert item[1]["json"] == (tmp_path / "once-seed0.json").read_text()
    copy = loading.restore(item, "velocity", spec.env_kwargs_for("velocity"))
    obs = np.random.default_rng(0).standard_normal((5, 15)).astype(np.float32)
    assert np.array_equal(copy.predict(obs)[0], pol.predict(obs)[0])
    assert len(calls) == 3 and os.path.dirname(calls[-1]) != str(tmp_path)
    # a scripted law travels as its description (rebuilt where it runs); a changed file is loaded again
    assert loading.portable({"kind": "clf", "n": 2}, None) == ("build", {"kind": "clf", "n": 2})
    os.utime(tmp_path / "once-seed0.json", ns=(1, 1))
    loading.load_safe(spec.runs[0])
    assert len(calls) == 4


def test_evaluation_imports_no_higher_layer():
    root = pathlib.Path(ev.__file__).parent
    for path in root.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            mods = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            for m in mods:
                assert not m.startswith(("ehss_gym.reporting", "ehss_gym.cli", "ehss_gym.study", "ehss_gym.train")), \
                    f"{path.name} imports {m}"


def test_harness_keeps_the_names_other_layers_use():
    # the training report and validation call ``from ehss_gym.evaluation import harness as ev``
    for name in ("evaluate", "EvalConfig", "object_spec", "scripted_spec", "learned_spec", "parse_policy",
                 "primary_score", "SCORE_CAP", "REFERENCE_POLICY", "PolicyError", "PolicySpec", "Results", "Episode",
                 "build_episodes", "check_fit", "rollout", "default_specs", "shipped_specs", "METRICS"):
        assert getattr(harness, name) is getattr(ev, name), name
    assert set(harness.__all__) >= {"evaluate", "EvalConfig", "Results", "primary_score", "SCORE_CAP"}
