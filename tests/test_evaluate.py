"""The evaluation harness: policy specs and their errors, the ruler's ratios and figures, ranking, determinism,
loading and the CLI."""

import ast
import csv
import json
import math
import os
import pathlib
import re
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
from ehss_gym.evaluation import harness, loading, scoring
from ehss_gym.evaluation import stats as ev_stats
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


def _m(trk=(1e-3, 1e-4), dst=(1e-2, 1e-3), eff=(100.0, 0.5), diverged=False, windows=(1.0, 0.5)):
    """Metrics of one episode: (trk_rmse, trk_iae), (dst_peak, dst_iae), (tv_u_rate, rms_u), the tracking and
    disturbance windows' durations [s]."""
    return {"trk_rmse": trk[0], "trk_iae": trk[1], "dst_peak": dst[0], "dst_iae": dst[1], "tv_u_rate": eff[0],
            "rms_u": eff[1], "diverged": diverged, "t_tracking": windows[0], "t_disturbance": windows[1]}


def test_class_ratios_by_hand():
    ref = _m()
    T = "velocity"
    # the reference against itself: exactly 1 in every class
    assert scoring.episode_log_ratios(ref, ref, False, T) == {"tracking": 0.0, "disturbance": 0.0, "effort": 0.0}
    assert set(scoring.episode_log_ratios(ref, ref, True, T)) == {"tracking", "disturbance", "chatter"}
    # halving both tracking metrics gives 1/2, doubling them 2: symmetric in log ratio, no cap
    half = scoring.episode_log_ratios(_m(trk=(5e-4, 5e-4)), _m(trk=(1e-3, 1e-3)), False, T)
    double = scoring.episode_log_ratios(_m(trk=(2e-3, 2e-3)), _m(trk=(1e-3, 1e-3)), False, T)
    assert math.exp(half["tracking"]) == pytest.approx(0.5, rel=1e-14)
    assert math.exp(double["tracking"]) == pytest.approx(2.0, rel=1e-14)
    assert half["tracking"] == pytest.approx(-double["tracking"], rel=1e-14)
    # sqrt of the product of the two ratios: RMSE x4, IAE x1 -> 2; TV x9, RMS current x1/4 -> 1.5
    assert math.exp(scoring.class_log_ratio(_m(trk=(4e-3, 1e-3)), _m(trk=(1e-3, 1e-3)), "tracking", T)) == \
        pytest.approx(2.0)
    assert math.exp(scoring.class_log_ratio(_m(eff=(900.0, 0.125)), ref, "effort", T)) == pytest.approx(1.5)
    huge = scoring.class_log_ratio(_m(trk=(1e3, 1e3)), _m(trk=(1e-3, 1e-3)), "tracking", T)
    assert math.exp(huge) == pytest.approx(1e6)  # no cap
    # the numeric floors (the ruler's before the physical ones): 0 against 0 is 1; 0 against 1e-10 is the floor's
    # ratio (1e-12 / 1e-10 on one metric of two)
    num = scoring.NUMERIC_FLOORS
    zero = _m(trk=(0.0, 1e-4), eff=(0.0, 0.0))
    assert scoring.class_log_ratio(zero, _m(trk=(0.0, 1e-4)), "tracking", T, num) == 0.0
    assert math.exp(scoring.class_log_ratio(zero, _m(trk=(1e-10, 1e-4)), "tracking", T, num)) == pytest.approx(0.1)
    assert math.exp(scoring.class_log_ratio(zero, _m(eff=(1e-8, 1e-9)), "effort", T, num)) == pytest.approx(
        math.sqrt(0.1 * 1.0))
    # no window, no class; a diverged episode (or reference) has no ratio at all
    assert "disturbance" not in scoring.episode_log_ratios(_m(dst=(math.nan, math.nan)), ref, False, T)
    assert scoring.episode_log_ratios(_m(diverged=True), ref, False, T) == {}
    assert scoring.episode_log_ratios(ref, _m(diverged=True), False, T) == {}


@pytest.mark.parametrize("task", ["velocity", "position"])
def test_physical_floors_blind_the_ruler_below_what_a_sensor_or_the_valve_resolves(task):
    """Below the physical floors a ratio is 1 whatever the numbers; above them the ruler is as before; a floor only
    takes the lower side of a ratio (a policy 10x the floor against a reference below it gets the ratio to the floor,
    not to the reference)."""
    f = scoring.PHYSICAL_FLOORS
    e = f.error[task]
    assert e == (1e-4 if task == "velocity" else 2 * math.pi / 2**20)
    assert f.current == pytest.approx(0.05) and f.tv == pytest.approx(2 * 0.05 / (2 * math.pi * 0.01))
    win = (1.2, 0.4)  # [s]
    tiny = _m(trk=(0.1 * e, 0.1 * e * win[0]), dst=(0.2 * e, 0.2 * e * win[1]), eff=(0.1 * f.tv, 0.1 * f.current),
              windows=win)
    tinier = _m(trk=(1e-3 * e, 1e-3 * e * win[0]), dst=(1e-3 * e, 1e-3 * e * win[1]),
                eff=(1e-3 * f.tv, 1e-3 * f.current), windows=win)
    assert scoring.episode_log_ratios(tinier, tiny, False, task) == {"tracking": 0.0, "disturbance": 0.0,
                                                                       "effort": 0.0}
    # with the numeric floors the same numbers rank: x1e-2 on every metric
    num = scoring.episode_log_ratios(tinier, tiny, False, task, scoring.NUMERIC_FLOORS)
    assert math.exp(num["tracking"]) == pytest.approx(1e-2) and math.exp(num["effort"]) == pytest.approx(1e-2)
    # an IAE's floor is the error floor over the IAE's window: an IAE at 3x that against one at the floor is 3x
    above = _m(trk=(10 * e, 10 * e * win[0]), windows=win)
    ratio = math.exp(scoring.class_log_ratio(above, tiny, "tracking", task))
    assert ratio == pytest.approx(10.0)  # sqrt(10 e / e * 10 e T / (e T))
    assert math.exp(scoring.class_log_ratio(above, _m(trk=(20 * e, 20 * e * win[0]), windows=win), "tracking",
                                            task)) == pytest.approx(0.5)
    with pytest.raises(KeyError):
        scoring.class_log_ratio(above, {k: v for k, v in tiny.items() if k != "t_tracking"}, "tracking", task)


def test_figures_gates_and_ranking_by_hand():
    # tracking ratios 2 and 8 -> 4 (geometric mean); disturbance 1/4 -> overall sqrt(4 * 1/4) = 1
    g, gc = scoring.figure_of({"tracking": [math.log(2.0), math.log(8.0)], "disturbance": [math.log(0.25)],
                               "effort": []})
    assert gc == {"tracking": pytest.approx(4.0), "disturbance": pytest.approx(0.25)} and g == pytest.approx(1.0)
    ok = {"diverged": False, "lost_track": False, "saturation": 0.0}
    assert scoring.failure([ok, ok]) == (False, 0)
    assert scoring.failure([ok, {**ok, "diverged": True}]) == (True, 1)
    assert scoring.failure([{**ok, "lost_track": True}, {**ok, "diverged": True}]) == (True, 2)
    assert scoring.failure([{**ok, "saturation": 0.10}]) == (False, 0)  # at the gate passes
    assert scoring.failure([{**ok, "saturation": 0.12}, {**ok, "saturation": 0.09}]) == (True, 0)  # mean 0.105
    pols = [("a", False, 0, 1.2), ("b", False, 0, 0.9), ("c", True, 2, 0.1), ("d", True, 1, 5.0),
            ("e", True, 0, 3.0), ("f", False, 0, math.nan)]
    order = sorted(pols, key=lambda p: scoring.rank_key(p[1], p[2], p[3], p[0]))
    assert [p[0] for p in order] == ["b", "a", "f", "e", "d", "c"]


def test_grouped_mean_ci_brackets_the_class_structured_mean():
    # two classes over 4 episodes (NaN = not a member): class means 1.0 and 3.0 -> grouped mean 2.0
    a = np.array([[1.0, 1.0, np.nan, 1.0]])
    b = np.array([[np.nan, 2.0, 4.0, np.nan]])
    assert ev_stats.grouped_mean([a, b]) == pytest.approx(2.0)
    lo, hi = ev_stats.grouped_mean_ci([a, b], n_boot=500, seed=1)
    assert lo <= 2.0 <= hi and lo >= 1.0 and hi <= 2.5  # class a is constant; b's mean lies in [2, 4]


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
    assert "figure_lo_seeds" in by[multi.name]  # a CI over training seeds exists with 2 seeds
    # safe weights that do not record the newer loop settings act in the legacy loop: listed apart, not compared; a
    # zip with no env spec is scored at the env's defaults (with a warning), today's loop, and compared
    assert by[multi.name]["earlier_loop"] and not by[zspec.name]["earlier_loop"]
    assert [c["policy"] for c in res.comparisons] == [zspec.name] * len(res.comparisons) and res.comparisons
    for d in by.values():
        assert d["n_episodes"] == 3 and math.isfinite(d["figure"])


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


def test_a_policy_recorded_in_another_loop_is_listed_apart():
    """A learned policy at sigma = 1e4 acts in another loop than today's defaults: no CLF rows at its settings are
    added, it is summarised but not ranked and not compared; a zero residual at the defaults is the reference law
    itself: figure exactly 1, class ratios to its base law exactly 1."""
    other = ev.object_spec("zero-residual-old", _FixedPolicy(value=0.0), env_kwargs={"task": "velocity", "sigma": 1e4})
    today = ev.object_spec("zero-residual", _FixedPolicy(value=0.0), env_kwargs={"task": "velocity"})
    res = ev.evaluate([ev.parse_policy("clf-n2"), other, today], TINY, workers=1, progress=False)
    assert {s.name for s in res.specs} == {"clf-n2", "zero-residual-old", "zero-residual"}
    by = {d["policy"]: d for d in res.summary}
    assert by["zero-residual-old"]["earlier_loop"] and by["zero-residual-old"]["rank"] == 0
    assert {by["clf-n2"]["rank"], by["zero-residual"]["rank"]} == {1, 2}
    assert by["zero-residual"]["figure"] == 1.0 and by["zero-residual-old"]["figure"] != pytest.approx(1.0)
    (c,) = res.comparisons
    assert c["policy"] == "zero-residual" and c["base_law"] == "clf-n2"
    assert all(c[f"{k}_ratio"] == 1.0 for k in ("tracking", "disturbance")) and c["improvement"] == 0.0
    rows = [r for r in res.rows if r["policy"] == "zero-residual"]
    assert all(r["q_overall"] == 1.0 for r in rows)


def test_a_residual_is_compared_with_the_scripted_law_whose_loop_it_acts_in():
    """A zero residual on the observer's loop is eso-n2 itself: its base law is eso-n2, not clf-n2, and its figure
    over that base law's is exactly 1 with a CI of [1, 1]; over clf-n2 it is eso-n2's ratio. A zero residual at the
    defaults has clf-n2 as both its best CLF and its base law: the same ratio and CI twice."""
    from ehss_gym.controllers import parse_scripted

    eso = parse_scripted("eso-n2", "velocity")
    on_eso = ev.object_spec("zero-on-eso", _FixedPolicy(value=0.0),
                            env_kwargs={"task": "velocity", **{k: v for k, v in eso.items() if k != "mode"}})
    today = ev.object_spec("zero-residual", _FixedPolicy(value=0.0), env_kwargs={"task": "velocity"})
    specs = [ev.parse_policy("clf-n2"), ev.parse_policy("eso-n2"), on_eso, today]
    res = ev.evaluate(specs, TINY, workers=1, progress=False)
    by = {c["policy"]: c for c in res.comparisons}
    c = by["zero-on-eso"]
    assert c["best_clf"] == "clf-n2" and c["base_law"] == "eso-n2"
    assert (c["ratio_to_base"], c["ratio_to_base_lo"], c["ratio_to_base_hi"]) == (1.0, 1.0, 1.0)
    fig = {d["policy"]: d["figure"] for d in res.summary}
    assert c["ratio_to_best"] == pytest.approx(fig["eso-n2"], rel=1e-12) and c["ratio_to_best"] != 1.0
    c = by["zero-residual"]
    assert c["base_law"] == "clf-n2" and c["ratio_to_base"] == c["ratio_to_best"] == 1.0
    assert c["ratio_to_base_lo"] == pytest.approx(1.0 - c["improvement_hi"], rel=1e-12)
    assert c["ratio_to_base_hi"] == pytest.approx(1.0 - c["improvement_lo"], rel=1e-12)


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
    held = [e for e in a if e.suite in ("heldout", "robustness")]
    steps = [e for e in a if e.suite == "step"]
    assert len(steps) == 2 * len(cfg.step_amplitudes)
    assert all(e.physical["friction"] == () and e.physical["noise_std"] == (0.0,) * 4 and e.physical["model"] is None
               and e.physical["reference"].family == "step" for e in steps)
    zero = [e for e in a if e.suite == "robustness" and e.sweep == "friction" and e.level == 0.0]
    assert zero and all(e.physical["friction"] == ((0.0,) + ev.SWEEP_WINDOW,) for e in zero)  # its window kept
    assert held and all(e.scenario_seed >= HELDOUT_SEED_BASE >= TRAIN_SEED_LIMIT for e in held)
    sweep = [e for e in a if e.suite == "robustness" and e.sweep == "friction" and e.level == 3.6]
    assert all(e.physical["friction"] == ((3.6,) + ev.SWEEP_WINDOW,) for e in sweep)
    mis = [e for e in a if e.suite == "robustness" and e.sweep == "mismatch" and e.level == 0.2]
    assert all(e.physical["plant"] != e.physical["model"] for e in mis)


def test_harness_ranks_a_badly_tuned_law_last():
    """A PID with a far too small proportional gain (and no I or D) loses track and ranks below the CLF laws: the
    failure gate puts it last; its tracking and disturbance figures are far above theirs (non-overlapping CIs)."""
    cfg = ev.EvalConfig(suites=("heldout",), tasks=("velocity",), heldout_episodes=8, episode_seconds=0.5,
                        n_boot=1000)
    detuned = ev.scripted_spec("pid", label="pid-detuned", gains={"velocity": (0.01, 0.0, 0.0)})  # mA per rad/s
    specs = [ev.parse_policy("clf-n2"), ev.parse_policy("clf-n4"), detuned]
    res = ev.evaluate(specs, cfg, workers=1, progress=False)
    block = {d["policy"]: d for d in res.summary}
    assert block["pid-detuned"]["rank"] == 3
    assert block["pid-detuned"]["failed"] and block["pid-detuned"]["n_failed"] >= 1
    assert block["pid-detuned"]["lost_track_rate"] > 0
    assert {block["clf-n2"]["rank"], block["clf-n4"]["rank"]} == {1, 2}
    assert not block["clf-n2"]["failed"] and not block["clf-n4"]["failed"]
    for cls in ("tracking", "disturbance"):
        worst_good_hi = max(block[n][f"{cls}_hi"] for n in ("clf-n2", "clf-n4"))
        assert block["pid-detuned"][f"{cls}_lo"] > 10 * worst_good_hi, cls  # non-overlapping 95 % CIs
    assert block["pid-detuned"]["trk_rmse"] > 100 * block["clf-n2"]["trk_rmse"]


def test_results_do_not_depend_on_workers():
    specs = [ev.parse_policy("clf-n2"), ev.object_spec("const", _FixedPolicy(value=0.05),
                                                        env_kwargs={"task": "velocity"})]
    one = ev.evaluate(specs, TINY, workers=1, progress=False)
    two = ev.evaluate(specs, TINY, workers=2, progress=False)
    assert two.workers == 2
    key = ("policy", "episode", "q_overall", "trk_rmse", "tv_u_rate", "max_abs_e")
    assert [tuple(repr(r[k]) for k in key) for r in one.rows] == [tuple(repr(r[k]) for k in key) for r in two.rows]
    # the constant residual changed the outcome (the policy's action reaches the plant)
    r = {(x["policy"], x["episode"]): x for x in one.rows}
    assert any(r[("const", e)]["rmse"] != r[("clf-n2", e)]["rmse"] for e in ("heldout-0", "heldout-1"))


def test_a_law_evaluated_on_both_tasks_acts_on_each_with_its_own_object():
    """A scripted law's item (its description) is the same for both tasks; the object made from it is not: a worker
    that ran the velocity episodes first must not score the position ones with the velocity PID (it did, at
    first, under the execution layer's cache)."""
    key = ("task", "episode", "q_overall", "trk_rmse", "tv_u_rate")
    for workers in (1, 2):
        mixed = ev.evaluate([ev.parse_policy("pid")], replace(TINY, tasks=("velocity", "position")), workers=workers,
                            progress=False)
        alone = ev.evaluate([ev.parse_policy("pid")], replace(TINY, tasks=("position",)), workers=workers,
                            progress=False)
        pos = [tuple(repr(r[k]) for k in key) for r in mixed.rows if r["task"] == "position" and r["policy"] == "pid"]
        assert pos and pos == [tuple(repr(r[k]) for k in key) for r in alone.rows if r["policy"] == "pid"]


# ---------------------------------------------------------------------------------------------------
# The CLI end to end (--quick is what CI runs)


LEARNED = "residual-ppo-position-n2"  # a shipped model: five seeds


def test_cli_quick_writes_the_report(tmp_path, capsys):
    """The quick form on every suite and both tasks, for the scripted laws and one shipped learned model (its five
    seeds, in an earlier loop: the report's section for those), with 2 held-out and 2 unmodelled episodes per task
    instead of 8 and 100 bootstrap replicates: the report's every path in half the work (.ci/run runs the whole
    default quick form, every shipped model included, twice)."""
    out = tmp_path / "cmp"
    rc = main(["evaluate", "--quick", "--episodes", "2", "--n-boot", "100", "--policies", *ev.SCRIPTED_DEFAULT,
               LEARNED, "--out", str(out), "--store", str(tmp_path / "jobs"), "--no-progress"])
    assert rc == 0
    for f in ("REPORT.md", "episodes.csv.gz", "summary.csv", "steps.csv", "figures/pareto_heldout.png",
              "figures/pareto_paper.png", "figures/pareto_robustness.png", "figures/pareto_unmodelled.png",
              "figures/paper_traces_velocity.png", "figures/paper_traces_position.png",
              "figures/robustness_velocity.png", "figures/metrics_heldout_velocity.png"):
        assert (out / f).is_file(), f
    text = (out / "REPORT.md").read_text()
    assert "`ehss evaluate" in text and "--quick" in text and f"ehss-gym {__version__}" in text
    # the header's wall time counts every phase: the phases add up to it (before, the bounds were left out)
    wall, phases = re.search(r"wall time ([\d.]+) s \(([^)]*)\)", text).groups()
    times = dict((k, float(v)) for k, v in re.findall(r"([a-z-]+) ([\d.]+) s", phases))
    assert list(times) == ["start-up", "setup", "episodes", "statistics", "bounds", "figures", "report"]
    assert abs(sum(times.values()) - float(wall)) <= 0.02 * float(wall) + 0.5, (wall, times)
    assert "q_tracking    = sqrt((trk_rmse / trk_rmse_R) * (trk_iae / trk_iae_R))" in text
    assert "overall figure G   = exp(mean over the classes present on the suite of log G_c)" in text
    assert "keeps the paper's start" in text and "## 5. Step suite" in text
    # the first screen answers "which policy is best": the held-out tables come before any detail
    assert text.index("**Held-out suite, velocity**") < text.index("## 1. The ruler")
    assert text.index("## 10. Settings") > text.index("## 8. Metrics")  # settings at the end
    for label in ("tracking RMSE", "disturbance peak", "RMSE", "IAE", "ITAE", "recovery on", "control TV",
                  "saturation", "divergence rate", "V decrease"):
        assert label in text
    cfg = ev.EvalConfig.quick(heldout_episodes=2)
    n_specs = len(ev.SCRIPTED_DEFAULT) + 1
    rows = comparison.read_episodes(str(out))
    per_task = (1 + 2 * cfg.heldout_episodes  # the heldout and the unmodelled suite
                + cfg.sweep_episodes * (len(cfg.friction_levels) + len(cfg.mismatch_levels)) + len(cfg.step_amplitudes))
    scripted = len(ev.SCRIPTED_DEFAULT)
    assert len(rows) >= scripted * 2 * per_task
    assert len(rows) <= n_specs * 2 * per_task * 10  # learned models add at most a few seeds per task
    assert {r["run"] for r in rows if r["policy"] == LEARNED} == {str(k) for k in range(5)}
    assert "## 7. Learned policies" in text and LEARNED in text.split("## 7. Learned policies")[1]
    ref = [r for r in rows if r["policy"] == ev.REFERENCE_POLICY and r["suite"] != "step"]
    assert all(float(r["q_overall"]) == 1.0 for r in ref)
    summary = _csv_rows(out / "summary.csv")
    # the step suite: its own table
    assert {r["suite"] for r in summary} == {"paper", "heldout", "robustness", "unmodelled"}
    steps = _csv_rows(out / "steps.csv")
    assert len({(r["task"], r["amplitude"]) for r in steps}) == 2 * len(cfg.step_amplitudes)
    assert all(0 < float(r["step_rise_time"]) < 0.5 for r in steps if r["policy"] == ev.REFERENCE_POLICY)
    assert not [p for p in os.listdir(out) if p.startswith(".tmp-")]  # no temp files left behind


def test_interrupted_run_keeps_previous_report(tmp_path, monkeypatch):
    res = ev.evaluate([ev.parse_policy("clf-n2")], TINY, workers=1, progress=False)
    out = tmp_path / "cmp"
    comparison.write_report(res, str(out))
    before = (out / "REPORT.md").read_text()
    assert "**No learned policy was evaluated**" in before and "\n\n\n" not in before
    assert "## 7. Learned policies\n\nNo learned policy was evaluated, so" in before

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
                 "REFERENCE_POLICY", "PolicyError", "PolicySpec", "Results", "Episode",
                 "build_episodes", "check_fit", "rollout", "default_specs", "shipped_specs", "METRICS"):
        assert getattr(harness, name) is getattr(ev, name), name
    assert set(harness.__all__) >= {"evaluate", "EvalConfig", "Results"}
    assert not hasattr(ev, "primary_score") and not hasattr(ev, "SCORE_CAP")  # the capped score is gone


def test_the_valve_floors_follow_the_rigs_valve():
    """The current and TV floors are the rig's valve's (0.5 % of its rated current, switched at its bandwidth), worked
    out here from the datasheet numbers by hand; Table I's rig gives the ruler's constants exactly; the error floors
    are the sensors', the same on every rig; the comparison of the second shipped rig states its own floors."""
    from ehss_gym.core.rig import TABLE_I, as_rig

    assert scoring.physical_floors(TABLE_I) == scoring.PHYSICAL_FLOORS == scoring.physical_floors(None)
    rig = as_rig("compact140")
    f = scoring.physical_floors(rig)
    threshold = rig.rated_current * 0.005  # [mA] 0.5 % of the rated current
    assert f.current == pytest.approx(threshold, rel=1e-12)
    assert f.tv == pytest.approx(threshold * 2 / (2 * math.pi * rig.plant.tau), rel=1e-12)
    assert f.error == scoring.PHYSICAL_FLOORS.error
    assert (f.tv, f.current) != (scoring.PHYSICAL_FLOORS.tv, scoring.PHYSICAL_FLOORS.current)
    assert f"{rig.rated_current:g} mA rated current" in f.rows()[-1][3]  # the RMS current's source names the rig's
    # an effort ratio below the rig's floors is 1, though it would rank under Table I's floors
    lo = _m(eff=(0.5 * f.tv, 0.5 * f.current))
    lower = _m(eff=(0.1 * f.tv, 0.1 * f.current))
    assert scoring.class_log_ratio(lower, lo, "effort", "velocity", f) == 0.0
    assert scoring.class_log_ratio(lower, lo, "effort", "velocity") < 0.0


def test_the_episode_table_is_gzip_with_the_same_bytes_for_the_same_rows(tmp_path):
    """The episode table round-trips through gzip; two writes of the same rows are the same bytes (no time stamp in the
    header: the local and the Ray backend are compared byte for byte); an earlier release's plain episodes.csv beside
    it is removed, so a report folder holds one episode table."""
    rows = [{"suite": "heldout", "policy": "clf-n2", "q_overall": 0.1 + 0.2}, {"suite": "paper", "policy": "pid"}]
    text = comparison.csv_text(rows, ["suite", "policy", "q_overall"])
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "episodes.csv").write_text("stale\n")
    comparison.write_episodes(str(tmp_path / "a" / comparison.EPISODES_FILE), text)
    comparison.write_episodes(str(tmp_path / comparison.EPISODES_FILE), text)
    f = comparison.EPISODES_FILE
    assert (tmp_path / "a" / f).read_bytes() == (tmp_path / f).read_bytes()
    assert not (tmp_path / "a" / "episodes.csv").exists()
    back = comparison.read_episodes(str(tmp_path / "a"))
    assert [r["policy"] for r in back] == ["clf-n2", "pid"]
    assert float(back[0]["q_overall"]) == 0.1 + 0.2 and back[1]["q_overall"] == ""


def test_the_default_chunk_gives_one_job_per_policy_run_task_and_suite():
    """The default evaluation's suites each fit one job (``EvalConfig.chunk``): a learned policy then acts on all the
    episodes of a suite in one batch, which fixes the batch its float32 forward pass rounds with; a smaller chunk
    splits the largest suites."""
    cfg = ev.EvalConfig()
    eps = ev.build_episodes(cfg)
    specs = [ev.parse_policy("clf-n2")]
    batches = harness.make_batches(specs, eps, cfg.chunk)
    groups = {(e.task, e.suite) for e in eps}
    assert len(batches) == len(groups) and sorted((b.task, b.episodes[0].suite) for b in batches) == sorted(groups)
    assert max(len(b.episodes) for b in batches) <= cfg.chunk
    assert len(harness.make_batches(specs, eps, 24)) > len(groups)


def test_a_policys_confidence_intervals_do_not_depend_on_the_policies_beside_it():
    """The bootstrap seeds are the policy's own (a hash of its name), not its place in the list: adding a policy to an
    evaluation, or reordering it, leaves every other policy's CIs as they were (committed episodes, held-out
    velocity)."""

    def value(v: str):
        if v in ("True", "False"):
            return v == "True"
        try:
            return float(v)
        except ValueError:
            return v

    keep = ("clf-n2", "dob-n2", "vinv-n2", "eso-n2")
    root = pathlib.Path(__file__).resolve().parents[1]
    rows = [{k: value(v) for k, v in r.items()} for r in comparison.read_episodes(str(root / "reports" / "comparison"))
            if r["suite"] == "heldout" and r["task"] == "velocity" and r["policy"] in keep]
    cfg = ev.EvalConfig(n_boot=200)
    wide, _ = scoring.summarize(rows, [ev.scripted_spec(n) for n in keep], cfg)
    narrow, _ = scoring.summarize(rows, [ev.scripted_spec(n) for n in ("eso-n2", "clf-n2")], cfg)
    a, b = (next(d for d in s if d["policy"] == "eso-n2") for s in (wide, narrow))
    keys = [k for k in a if k.endswith(("_lo", "_hi")) or k.startswith("poi")]
    assert keys and all(a[k] == b[k] or (a[k] != a[k] and b[k] != b[k]) for k in keys)
    assert math.isfinite(a["figure_lo"]) and a["figure_lo"] < a["figure"] < a["figure_hi"]
