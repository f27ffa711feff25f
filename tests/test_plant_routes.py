"""Every route a plant takes: the env's ``plant`` setting (a record, a dict, a file path, a shipped name), the
random distribution drawn around it, the PID tuned on it, and the commands' ``--plant`` (simulate, evaluate,
headroom, train), each output naming it; Table I's loop unchanged without one."""

from __future__ import annotations

import json
import warnings

import gymnasium as gym
import numpy as np
import pytest

import ehss_gym  # noqa: F401  (registers the env)
from ehss_gym.cli import main
from ehss_gym.controllers import PID_GAINS, PID_RELAY, PIDPolicy, tune_pid
from ehss_gym.controllers import pid as pid_module
from ehss_gym.core.params import PlantParams
from ehss_gym.core.rig import TABLE_I, as_rig, shipped_plants
from ehss_gym.core.scenarios import MISMATCH_PARAMS, controller_mismatch
from ehss_gym.envs import EnvConfig
from ehss_gym.envs.config import PlantWarning
from ehss_gym.envs.lanes import Lanes
from ehss_gym.envs.law_table import LawSettingsError, load_law_table
from ehss_gym.evaluation import harness
from ehss_gym.evaluation.loading import load_run
from ehss_gym.evaluation.specs import scripted_spec
from ehss_gym.evaluation.suites import EvalConfig
from ehss_gym.reporting.comparison import read_episodes
from ehss_gym.study.headroom import HeadroomConfig, plan
from ehss_gym.train.config import Config

RIG = as_rig("compact140")


@pytest.mark.parametrize("how", ["record", "params", "dict", "path", "name"])
def test_the_env_takes_a_plant_as_a_record_a_dict_or_a_file(how):
    value = {"record": RIG, "params": RIG.plant, "dict": RIG.as_dict(), "path": shipped_plants()["compact140"],
             "name": "compact140"}[how]
    env = gym.make("ehss_gym:EHSSTracking-v0", plant=value, scenario="paper", episode_seconds=0.01)
    cfg = env.unwrapped.config
    assert cfg.plant.plant == RIG.plant and cfg.template().plant == RIG.plant
    assert cfg.current_limit == (RIG.rated_current if how != "params" else 10.0)  # a bare PlantParams: 10 mA
    env.reset(seed=0)
    lanes = env.unwrapped._lanes
    assert lanes.plant[0].tolist() == RIG.plant.as_array().tolist()
    assert lanes.model[0].tolist() == RIG.controller_model.as_array().tolist()


def test_random_episodes_draw_their_mismatch_around_the_plant_and_keep_its_model():
    env = gym.make("ehss_gym:EHSSTracking-v0", plant=RIG, episode_seconds=0.01)
    lanes = env.unwrapped._lanes
    for seed in range(20):
        _, info = env.reset(seed=seed)
        scaling = info["scenario"]["plant_scaling"]
        sc = env.unwrapped.scenario
        assert sc.model == RIG.plant  # the controller keeps the rig's nominal parameters
        for name in MISMATCH_PARAMS:
            assert 0.8 <= scaling[name] <= 1.2
            assert getattr(sc.plant, name) == pytest.approx(scaling[name] * getattr(RIG.plant, name), rel=1e-15)
        assert lanes.plant[0].tolist() == sc.plant.as_array().tolist()
        for name in ("d_m", "K", "tau", "V_m", "rho", "c_d"):  # not drawn: the rig's own
            assert getattr(sc.plant, name) == getattr(RIG.plant, name)
    # a plant file's own model is what the controller keeps
    own = as_rig({**RIG.as_dict(), "model": {"J": 0.02}})
    env = gym.make("ehss_gym:EHSSTracking-v0", plant=own, episode_seconds=0.01)
    env.reset(seed=1)
    assert env.unwrapped.scenario.model.J == 0.02 and env.unwrapped._lanes.model[0][0] == 0.02


def test_a_bad_plant_setting_is_a_clear_error():
    with pytest.raises(ValueError, match=r"plant.*\[plant\]: P_s \(supply pressure\) \[Pa\]"):
        gym.make("ehss_gym:EHSSTracking-v0", plant={**TABLE_I.as_dict(), "plant": {**PlantParams().as_dict(),
                                                                                   "P_s": 0.0}})
    with pytest.raises(ValueError, match=r"plant must be a TOML file path"):
        EnvConfig.from_kwargs({"plant": 3.5})
    with pytest.raises(ValueError, match=r"file not found"):
        EnvConfig.from_kwargs({"plant": "no-such-rig.toml"})


def test_table_i_is_the_default_and_its_file_changes_nothing():
    base = EnvConfig.from_kwargs({"task": "position"})
    same = EnvConfig.from_kwargs({"task": "position", "plant": "table1"})
    assert base.plant == same.plant == TABLE_I and not controller_mismatch(base.template(), same.template())
    assert (base.template().plant, base.template().model) == (same.template().plant, same.template().model)
    assert base.current_limit == 10.0


def test_the_pids_relay_experiment_runs_on_the_plant_it_will_control(monkeypatch):
    """Every tuning episode of the PID on an env with a plant runs on that plant (the relay experiment included),
    the result differs from Table I's, and a second PID on the same plant reuses it."""
    loaded = []
    real_load = Lanes.load

    def spy(self, b, sc, base=None):
        loaded.append(sc.plant)
        return real_load(self, b, sc, base)

    monkeypatch.setattr(Lanes, "load", spy)
    monkeypatch.setattr(pid_module, "_TUNED", {})
    cfg = EnvConfig.from_kwargs({"task": "velocity", "mode": "direct", "plant": RIG})
    out = tune_pid(cfg, progress=False)
    assert len(loaded) > 20 and all(p == RIG.plant for p in loaded)
    assert (out["Ku"], out["Tu"]) != PID_RELAY[("velocity", "direct")]
    n = len(loaded)
    pol = PIDPolicy(cfg)  # tuned for its env's settings: the same plant, from the cache
    assert len(loaded) == n and (pol.kp, pol.ki, pol.kd) == out["gains"]
    assert out["gains"] != PID_GAINS[("velocity", "direct")]
    # Table I's env keeps the stored gains (no tuning run)
    table = PIDPolicy(EnvConfig.from_kwargs({"task": "velocity", "mode": "direct", "plant": "table1"}))
    assert (table.kp, table.ki, table.kd) == PID_GAINS[("velocity", "direct")] and len(loaded) == n


def test_simulate_names_the_plant_in_its_summary_csv_and_npz(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["simulate", "--plant", "compact140", "--t-end", "0.3", "--out", str(out)]) == 0
    captured = capsys.readouterr()
    text = captured.out
    assert f"plant: {RIG.label}, rated current 15 mA" in text and "limit=15 mA" in text
    assert "note: the CLF law's settings are those tuned for Table I" in captured.err
    assert open(f"{out}.csv").readline().startswith(f"# plant: {RIG.label}")
    data = np.load(f"{out}.npz")
    assert str(data["plant"]) == RIG.label and str(data["plant_hash"]) == RIG.hash
    assert data["plant_values"].tolist() == RIG.plant.as_array().tolist()
    assert list(data["plant_fields"]) == list(PlantParams._fields)


def test_simulate_refuses_a_bad_plant_file_naming_the_key(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("[datasheet]\nrated_current_mA = 15\n")
    with pytest.raises(SystemExit) as exc:
        main(["simulate", "--plant", str(bad), "--out", str(tmp_path / "x")])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "argument --plant" in err and "missing key(s) ['rated_flow_lpm'" in err


def test_evaluate_runs_every_suite_on_the_plant_and_its_csvs_and_report_name_it(tmp_path, capsys):
    out = tmp_path / "ev"
    rc = main(["evaluate", "--plant", "compact140", "--policies", "clf-n2", "pid", "--suite", "heldout",
               "--task", "velocity", "--episodes", "2", "--workers", "1", "--no-store", "--no-progress",
               "--out", str(out), "--n-boot", "100"])
    assert rc == 0
    assert f"plant: {RIG.label}" in capsys.readouterr().out
    rows = read_episodes(str(out))
    assert rows and all(r["plant"] == RIG.label for r in rows)
    assert open(out / "summary.csv").readline().startswith("plant,")
    assert f"**Plant**: {RIG.label}" in (out / "REPORT.md").read_text()


def test_headroom_and_train_take_the_plant():
    cfg = HeadroomConfig.quick_config(tasks=("velocity",), plant=RIG)
    jobs = plan(cfg)
    assert jobs and all(j.config["env_kwargs"]["plant"] == RIG for j in jobs)
    assert all(ep.physical["plant"] == RIG.plant or ep.physical["model"] == RIG.plant
               for j in jobs for ep in j.config["episodes"])
    run = Config(plant="compact140", timesteps=1).validate()
    kw = run.full()["env_kwargs"]
    assert as_rig(kw["plant"]) == RIG and EnvConfig.from_kwargs(kw).plant == RIG
    assert run.run_name() != Config(timesteps=1).run_name()
    with pytest.raises(Exception, match=r"--plant: .*file not found"):
        Config(plant="nothere.toml").validate()


# --- law settings tuned for the plant -------------------------------------------------------------------------

LAWS = {"plant": {"label": RIG.label, "hash": RIG.hash},
        "velocity": {"default_n": 2, "clf-n2": {"sigma": 7e5, "fr": 100.0, "smoothing": 50.0, "layer_gain": 4.0},
                     "clf-n4": {"sigma": 2e6, "fr": 90.0, "smoothing": 0.0, "layer_gain": 0.0},
                     "dob-n2": {"dob_hz": 35.0, "smoothing": 60.0, "layer_gain": 5.0},
                     "pid": {"kp": 0.2, "ki": 0.5, "kd": 0.004}}}


def test_the_env_takes_the_law_settings_row_of_its_n_and_warns_without_them(tmp_path):
    path = tmp_path / "law_settings.json"
    path.write_text(json.dumps(LAWS))
    for value in (str(path), LAWS, load_law_table(path)):
        with warnings.catch_warnings():
            warnings.simplefilter("error", PlantWarning)  # tuned for this plant: no warning
            cfg = gym.make("ehss_gym:EHSSTracking-v0", plant=RIG, law_settings=value).unwrapped.config
        assert (cfg.sigma, cfg.fr, cfg.smoothing, cfg.layer_gain) == (7e5, 100.0, 50.0, 4.0)
    four = EnvConfig.from_kwargs({"plant": RIG, "law_settings": LAWS, "n": 4, "smoothing": 9.0})
    assert (four.sigma, four.fr, four.smoothing) == (2e6, 90.0, 9.0)  # an explicit setting wins
    six = EnvConfig.from_kwargs({"plant": RIG, "law_settings": LAWS, "n": 6})
    assert six.sigma == 7e5  # an n without a row: the default n's
    with pytest.warns(PlantWarning, match=r"tuned for Table I, and the plant is compact 140 bar rig"):
        gym.make("ehss_gym:EHSSTracking-v0", plant=RIG)
    with pytest.warns(PlantWarning, match=r"tuned on compact 140 bar rig .* and the plant is Table I"):
        gym.make("ehss_gym:EHSSTracking-v0", law_settings=LAWS)
    with pytest.raises(ValueError, match=r"law_settings: law settings \(dict\) have no row for task 'position'"):
        EnvConfig.from_kwargs({"task": "position", "law_settings": LAWS})


@pytest.mark.parametrize("content, pattern", [
    ({"velocity": {"clf-n2": {"sigma": "7e5", "fr": 1.0, "smoothing": 0.0, "layer_gain": 0.0}}},
     r"velocity.clf-n2.sigma \[unit of s\] must be a finite number in \(0, inf\), got '7e5'"),
    ({"velocity": {"clf-n3": {"sigma": 1.0, "fr": 1.0, "smoothing": 0.0, "layer_gain": 0.0}}},
     r"clf-n3's n must be an even integer"),
    ({"velocity": {"clf-n2": {"sigma": 1.0, "fr": 1.0}}}, r"velocity.clf-n2: missing key\(s\) \['smoothing'"),
    ({"velocity": {"clf-n2": {"sigma": 1.0, "fr": 1.0, "smoothing": 0.0, "layer_gain": 0.0}, "pid": {"kp": -1}}},
     r"velocity: pid: missing key|velocity.pid"),
    ({"torque": {}}, r"unknown key\(s\) \['torque'\]"),
    ({"velocity": {"default_n": 4, "clf-n2": {"sigma": 1.0, "fr": 1.0, "smoothing": 0.0, "layer_gain": 0.0}}},
     r"default_n = 4 has no clf-n4 row"),
])
def test_a_bad_law_settings_file_is_a_clear_error(content, pattern, tmp_path):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(content))
    with pytest.raises(LawSettingsError, match=pattern):
        load_law_table(path)
    with pytest.raises(SystemExit):
        main(["evaluate", "--law-settings", str(path), "--out", str(tmp_path / "x")])


def test_evaluate_gives_each_scripted_law_its_tuned_row(tmp_path):
    """--law-settings: clf-n<k> takes its n's row, dob-n2 its observer row per task, the PID its gains."""
    cfg = EvalConfig(plant=RIG, law_settings=LAWS, tasks=("velocity",))
    specs = {s.name: harness.on_plant(s, cfg, []) for s in map(scripted_spec, ("clf-n4", "dob-n2", "pid"))}
    kw4 = EnvConfig.from_kwargs(specs["clf-n4"].env_kwargs_for("velocity"))
    assert (kw4.sigma, kw4.fr, kw4.current_limit) == (2e6, 90.0, 15.0)
    dob = EnvConfig.from_kwargs(specs["dob-n2"].env_kwargs_for("velocity"))
    assert (dob.dob_hz, dob.smoothing, dob.layer_gain, dob.sigma) == (35.0, 60.0, 5.0, 7e5)
    pid = load_run(specs["pid"].runs[0], "velocity", specs["pid"].env_kwargs_for("velocity"))
    assert (pid.kp, pid.ki, pid.kd) == (0.2, 0.5, 0.004) and pid.config.plant == RIG


def test_reproduce_refuses_a_plant_and_says_where_to_go(capsys):
    assert main(["reproduce", "--plant", "compact140", "--quick"]) == 2
    assert "ehss evaluate --plant FILE" in capsys.readouterr().err
