"""The baselines' tuning: the one search routine, the defaults rule, the command, and the env's per-n defaults
against the shipped reports/baselines/tuned.json."""

from __future__ import annotations

import json
import math
import pathlib

import pytest

from ehss_gym.controllers import DOB_ROWS, PID_GAINS, PID_RELAY_GAINS
from ehss_gym.core.rig import as_rig
from ehss_gym.envs import EnvConfig
from ehss_gym.envs.config import DEFAULT_N, DEFAULTS, LAW_DEFAULTS, LAW_KEYS
from ehss_gym.envs.law_table import load_law_table
from ehss_gym.evaluation.specs import REFERENCE_POLICY, scripted_spec
from ehss_gym.study.baselines import (
    ANCHOR,
    BASELINES,
    BUDGET,
    LAW_NS,
    PID_START,
    Axis,
    Baseline,
    TuneSettings,
    default_n,
    dob_row,
    objective,
    search,
    tune_row,
)

ROOT = pathlib.Path(__file__).parents[1]
TUNED = ROOT / "reports" / "baselines" / "tuned.json"


def _bowl(target: dict, calls: list):
    """A synthetic objective: squared log distance to ``target`` (0 at it), in the search's order format."""
    def evaluate(p: dict) -> dict:
        calls.append(dict(p))
        d = sum((math.log10(p[k]) - math.log10(v)) ** 2 if p[k] > 0 else 100.0 for k, v in target.items())
        return {"key": (False, 0, False, d, ""), "figure": d, "classes": {}, "failed": False, "n_failed": 0,
                "saturation": 0.0}
    return evaluate


def test_search_finds_a_known_minimum_within_the_grid_resolution_and_spends_the_budget():
    axes = (Axis("a", 1e2, 1e9, 1.0), Axis("b", 20.0, 200.0, 0.25), Axis("c", 0.1, 1e6, 1.0, zero=True))
    target = {"a": 3.7e5, "b": 47.0, "c": 2.2e2}  # off every grid point
    calls: list = []
    res = search(axes, {"a": 1e5, "b": 60.0, "c": 1e3}, _bowl(target, calls), budget=40)
    assert res["used"] == 40 == len(calls) == len(res["history"])
    assert len({tuple(sorted(c.items())) for c in calls}) == 40  # no point evaluated twice
    for ax in axes:
        err = abs(math.log10(res["best"][ax.name]) - math.log10(target[ax.name]))
        assert err < ax.log_step / 4, (ax.name, err)  # better than the grid: the refinement narrowed it
    # the first evaluation is the start, then each axis' grid with the others at the incumbent (the start's own
    # grid point is not evaluated again)
    assert calls[0] == {"a": 1e5, "b": 60.0, "c": 1e3}
    assert [c["a"] for c in calls[1:8]] == pytest.approx([g for g in axes[0].grid() if g != pytest.approx(1e5)])
    assert all(c["b"] == 60.0 for c in calls[1:8])


def test_search_keeps_the_zero_point_and_the_start_when_nothing_is_better():
    axes = (Axis("a", 1.0, 100.0, 1.0), Axis("w", 0.1, 10.0, 1.0, zero=True))

    def evaluate(p):  # best with w off, a anywhere near 10
        d = (math.log10(p["a"]) - 1.0) ** 2 + (0.0 if p["w"] == 0.0 else 1.0 + p["w"])
        return {"key": (False, 0, False, d, ""), "figure": d, "classes": {}, "failed": False, "n_failed": 0,
                "saturation": 0.0}

    res = search(axes, {"a": 10.0, "w": 1.0}, evaluate, budget=12)
    assert res["best"] == {"a": 10.0, "w": 0.0} and res["used"] == 12


def test_search_climbs_out_of_an_infeasible_start_and_prefers_feasible_points():
    axes = (Axis("a", 1.0, 1e4, 1.0),)

    def evaluate(p):  # feasible only for a >= 100; infeasible points ordered by their failed count
        failed = p["a"] < 100.0
        key = (failed, int(100.0 / p["a"]) if failed else 0, False, 1.0 / p["a"] if failed else p["a"], "")
        return {"key": key, "figure": key[3], "classes": {}, "failed": failed, "n_failed": key[1],
                "saturation": 0.0}

    res = search(axes, {"a": 1.0}, evaluate, budget=10)
    assert res["best"]["a"] == pytest.approx(100.0) and not res["best_out"]["failed"]


def test_objective_is_the_rulers_figure_with_the_gate():
    base = {"diverged": False, "lost_track": False, "saturation": 0.0, "trk_rmse": 1.0, "trk_iae": 1.0,
            "dst_peak": 1.0, "dst_iae": 1.0, "tv_u_rate": 1.0, "rms_u": 1.0, "t_tracking": 1.0, "t_disturbance": 0.5}
    better = {**base, "trk_rmse": 0.25, "trk_iae": 0.25}  # tracking x1/4, disturbance and effort x1
    out = objective([better, better], [base, base], [False, True], "velocity")
    assert out["classes"] == pytest.approx({"tracking": 0.25, "disturbance": 1.0, "effort": 1.0, "chatter": 1.0})
    assert out["figure"] == pytest.approx(0.25 ** 0.25) and not out["failed"]
    lost = objective([better, {**better, "lost_track": True}], [base, base], [False, False], "velocity")
    assert lost["failed"] and lost["n_failed"] == 1 and lost["key"] > out["key"]
    sat = objective([{**better, "saturation": 0.2}], [base], [False], "velocity")
    assert sat["failed"] and sat["n_failed"] == 0


@pytest.mark.parametrize(("objs", "want"), [({2: 1.0, 4: 0.99, 6: 0.985}, 2),  # within 2 %: the smallest kept
                                            ({2: 1.0, 4: 0.97, 6: 0.975}, 4),  # 3 % lower: n = 4
                                            ({2: 1.0, 4: 1.2, 6: 0.9}, 6)])
def test_defaults_rule_keeps_a_smaller_n_unless_a_larger_one_is_lower_by_more_than_2_percent(objs, want):
    tuned = {f"velocity/clf-n{n}": {"objective": g, "failed": False, "n_failed": 0} for n, g in objs.items()}
    assert default_n(tuned, "velocity")["n"] == want


def test_defaults_rule_skips_a_failed_law():
    tuned = {f"velocity/clf-n{n}": {"objective": g, "failed": n == 4, "n_failed": int(n == 4)}
             for n, g in {2: 1.0, 4: 0.5, 6: 1.01}.items()}
    assert default_n(tuned, "velocity")["n"] == 2


def test_every_row_has_a_valid_space_and_start():
    assert BUDGET == 64
    for row in (*BASELINES, dob_row("velocity"), dob_row("position")):
        inherited = {k for _, keys in row.inherit for k in keys}
        assert set(row.start) | inherited >= {ax.name for ax in row.axes}, row.name
        assert all(src in {r.name for r in BASELINES} for src, _ in row.inherit)
        for ax in row.axes:
            v = row.start.get(ax.name, ax.lo)
            assert ax.lo <= v <= ax.hi or v == 0.0, (row.name, ax.name)
            g = ax.grid()
            assert g[-1] == pytest.approx(ax.hi) and g[1 if ax.zero else 0] == pytest.approx(ax.lo)
    assert PID_START == {t: dict(zip(("kp", "ki", "kd"), PID_RELAY_GAINS[(t, "direct")])) for t in PID_START}


def test_a_row_takes_its_inherited_settings_from_the_row_it_names(monkeypatch):
    """The residual rows' hook: searched inherited settings start at the source's tuned value, the others are held."""
    from ehss_gym.study import baselines as B

    seen = []

    def fake(task, settings, episodes, seconds):
        seen.append(dict(settings))
        m = {"diverged": False, "lost_track": False, "saturation": 0.0, "trk_rmse": 1.0, "trk_iae": 1.0,
             "dst_peak": 1.0, "dst_iae": 1.0, "tv_u_rate": 1.0, "rms_u": 1.0, "t_tracking": 1.0,
             "t_disturbance": 0.5}
        return [{**m, "trk_rmse": abs(math.log10(settings["f"] / 7.0)) + 1.0}]

    monkeypatch.setitem(B.RUNNERS, "fake", fake)
    row = Baseline("velocity/x", "velocity", "fake", (Axis("f", 1.0, 100.0, 1.0), Axis("w", 1.0, 10.0, 1.0)),
                   {"f": 10.0}, {"n": 2}, inherit=(("velocity/src", ("sigma", "w")),))
    tuned = {"velocity/src": {"settings": {"sigma": 3e5, "w": 4.0, "fr": 50.0}}}
    anchor = ([{"diverged": False, "trk_rmse": 1.0, "trk_iae": 1.0, "dst_peak": 1.0, "dst_iae": 1.0,
                "tv_u_rate": 1.0, "rms_u": 1.0, "t_tracking": 1.0, "t_disturbance": 0.5}], [False])
    out = tune_row(row, tuned, TuneSettings(budget=9, episodes=1), {"velocity": anchor})
    assert seen[0] == {"n": 2, "sigma": 3e5, "f": 10.0, "w": 4.0}  # w starts at the source's, sigma is held
    assert all(s["sigma"] == 3e5 and "fr" not in s for s in seen)
    assert out["evaluations_used"] == 9 and out["settings"]["sigma"] == 3e5
    assert abs(math.log10(out["tuned"]["f"] / 7.0)) < 0.5


def test_baselines_command_writes_its_report_and_law_settings(tmp_path):
    from ehss_gym.cli import main

    out = tmp_path / "b"
    argv = ["baselines", "--budget", "3", "--episodes", "2", "--seconds", "0.3", "--check-episodes", "2",
            "--compensator-episodes", "2", "--no-progress", "--out", str(out)]
    assert main(argv) == 0
    res = json.loads((out / "tuned.json").read_text(), parse_constant=lambda c: pytest.fail(f"non-finite {c}"))
    assert res["settings"]["budget"] == 3 and res["command"].startswith("ehss baselines --budget 3")
    assert set(res["baselines"]) == {r.name for r in BASELINES}
    assert {"velocity/dob-n2", "position/dob-n2"} <= set(res["baselines"])  # the observer, by the same search
    for name, r in res["baselines"].items():
        assert r["evaluations_used"] == len(r["evaluations"]) <= 3, name
    for task in ("velocity", "position"):
        assert res["defaults"][task]["n"] in LAW_NS
        assert (out / f"convergence_{task}.png").stat().st_size > 0
        assert res["check"][task]["tuned"]["episodes"] == 2
    text = (out / "BASELINES.md").read_text()
    assert text.splitlines()[2].startswith("Generated by `ehss baselines --budget 3")
    assert "a smaller n is kept unless a larger one is lower by more than 2 %" in text
    assert "**Plant**: Table I (built in, #" in text and "Held-out check of the tuned n = 2 law" in text
    table = load_law_table(out / "law_settings.json")  # what --law-settings takes
    for task in ("velocity", "position"):
        laws = table.task(task)
        assert laws.default_n == res["defaults"][task]["n"]
        assert laws.clf[2] == res["baselines"][f"{task}/clf-n2"]["tuned"]
        assert laws.dob == {k: res["baselines"][f"{task}/dob-n2"]["settings"][k]
                            for k in ("dob_hz", "smoothing", "layer_gain")}
        assert laws.pid == tuple(res["baselines"][f"{task}/pid"]["settings"][k] for k in ("kp", "ki", "kd"))
        # the last stage: each compensator's whole grid on the tuned n = 2 law, its choice a row of the table
        for kind, n_cands in (("dcomp", 7), ("vinv", 25)):
            r = res["compensators"][task][kind]
            assert len(r["evaluations"]) == n_cands and laws.compensators[kind] == r["chosen"]
            assert r["chosen"] in [e["point"] for e in r["evaluations"]]
    assert "## The compensators of the unmodelled valve and sensors" in text and "| velocity | vinv-n2 |" in text
    assert "on 2 training scenarios (seeds 0..1) drawn with the unmodelled effects" in text
    assert res["settings"]["compensator_episodes"] == 2


def test_the_quick_form_is_a_usable_tuning():
    q = TuneSettings.quick()
    assert (q.budget, q.episodes, q.seconds, q.check_episodes) == (32, 12, 2.0, 48)
    assert q.compensator_episodes == TuneSettings().compensator_episodes == 48  # 12 let noise pick a size
    grid = sum(len(ax.grid()) for ax in BASELINES[0].axes) - 3  # every axis' grid, the start's own points once
    assert grid < q.budget, "a quick run does not finish one pass over the law's grids"


def test_on_another_plant_the_pid_starts_at_the_relay_gains_on_it(monkeypatch):
    from ehss_gym.study import baselines as B

    calls = []
    monkeypatch.setattr(B, "tune_pid", lambda cfg, progress=True: calls.append(cfg.plant) or {"gains": (1.0, 2.0,
                                                                                                        3.0)})
    rig = as_rig("compact140")
    rows = {r.name: r for r in B.baselines_for(rig)}
    assert rows["velocity/pid"].start == {"kp": 1.0, "ki": 2.0, "kd": 3.0} and calls == [rig, rig]
    assert rows["velocity/pid"].axes[0].lo == pytest.approx(0.01) and rows["velocity/clf-n2"] == BASELINES[0]
    assert B.baselines_for(None) is BASELINES


# --- the shipped result and the env's defaults ------------------------------------------------------------------


def _shipped() -> dict:
    res = json.loads(TUNED.read_text())
    assert res["settings"]["budget"] == BUDGET and res["settings"]["episodes"] == 48, "a quick run was shipped"
    return res


def test_env_per_n_law_defaults_are_the_shipped_tuning():
    """LAW_DEFAULTS restates reports/baselines/tuned.json (made by `ehss baselines`), DEFAULT_N its rule's outcome,
    and an env made with n = k and no law settings takes n = k's tuned values."""
    res = _shipped()
    for task in ("velocity", "position"):
        assert DEFAULT_N[task] == res["defaults"][task]["n"]
        for n in LAW_NS:
            tuned = res["baselines"][f"{task}/clf-n{n}"]["tuned"]
            row = LAW_DEFAULTS[task][n]
            assert {k: getattr(row, k) for k in LAW_KEYS} == tuned, (task, n)
            cfg = EnvConfig.from_kwargs({"task": task, "n": n})
            assert {k: getattr(cfg, k) for k in LAW_KEYS} == tuned, (task, n)
        td = getattr(DEFAULTS, task)
        assert {k: getattr(td, k) for k in LAW_KEYS} == res["baselines"][f"{task}/clf-n{DEFAULT_N[task]}"]["tuned"]
    assert res["anchor"] == ANCHOR


def test_reference_policy_and_pid_gains_follow_the_shipped_tuning():
    res = _shipped()
    assert {DEFAULT_N[t] for t in DEFAULT_N} == {DEFAULTS.n}  # one default n for both tasks
    assert REFERENCE_POLICY == f"clf-n{DEFAULTS.n}"
    for task in ("velocity", "position"):
        tuned = res["baselines"][f"{task}/pid"]["tuned"]
        assert PID_GAINS[(task, "direct")] == (tuned["kp"], tuned["ki"], tuned["kd"])


def test_dob_rows_are_the_shipped_tuning_and_reach_the_evaluation():
    """DOB_ROWS restates the tuned dob-n2 rows of reports/baselines/tuned.json, and ``dob-n2`` acts with them on each
    task (an explicit observer setting keeps its own value)."""
    res = _shipped()
    for task in ("velocity", "position"):
        tuned = res["baselines"][f"{task}/dob-n2"]["tuned"]
        assert DOB_ROWS[task] == tuned, task
        kw = scripted_spec("dob-n2").env_kwargs_for(task)
        assert {k: kw[k] for k in tuned} == tuned, task
    assert scripted_spec("dob-n2", label="dob-20", env_overrides={"dob_hz": 20.0}).env_kwargs_for("velocity")[
        "dob_hz"] == 20.0
