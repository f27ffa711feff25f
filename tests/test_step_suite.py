"""The evaluation's step suite: episodes from rest, step metrics from the agent-rate trace of the true output, and
the ratio to the physical bound when the bound is available (the report never makes one up)."""

import csv
import math
from types import SimpleNamespace

import pytest

from ehss_gym import evaluation as ev
from ehss_gym.core.response import step_metrics
from ehss_gym.core.sim import simulate
from ehss_gym.envs import EnvConfig
from ehss_gym.evaluation.suites import STEP_SECONDS, STEP_TIME
from ehss_gym.reporting import comparison

pytestmark = pytest.mark.xdist_group("step_suite")  # one worker computes the step results (a module fixture) once

CFG = ev.EvalConfig(suites=("step",), tasks=("velocity",), step_amplitudes=(0.5, -1.0), n_boot=100)


@pytest.fixture(scope="module")
def step_results():
    return ev.evaluate([ev.parse_policy("clf-n2"), ev.parse_policy("clf-n4")], CFG, workers=1, progress=False)


def test_step_metrics_match_the_simulated_step_at_the_control_rate(step_results):
    """The trace's true output at the agent rate gives the step metrics of the same loop simulated and logged at
    every control period, to within one agent step; the IAE against r is the accumulator's, exactly."""
    cfg = EnvConfig.from_kwargs({"task": "velocity"})
    refs = {ep.level: ep.physical["reference"] for ep in ev.build_episodes(CFG)}
    for r in (x for x in step_results.rows if x["policy"] == "clf-n2"):
        sc = cfg.template().replace(reference=refs[r["level"]], friction=(), noise_std=(0.0,) * 4,
                                    t_end=STEP_SECONDS["velocity"], log_interval=cfg.control_period)
        traj = simulate(sc)
        want = step_metrics(traj.t, traj.y, STEP_TIME, 0.0, r["level"])
        assert r["step_rise_time"] == pytest.approx(want["rise_time"], abs=cfg.agent_dt)
        assert r["step_settling_time"] == pytest.approx(want["settling_time"], abs=cfg.agent_dt)
        assert r["step_overshoot"] == pytest.approx(want["overshoot"], abs=0.5)
        assert r["iae_r"] == pytest.approx(traj.metrics()["iae_r"], rel=1e-12)
        assert 0 < r["step_rise_time"] < 0.1 and not r["diverged"]


def test_the_ratio_to_the_bound_is_shown_only_with_the_bound(step_results, tmp_path, monkeypatch):
    monkeypatch.setattr(comparison, "bound_function", lambda: None)
    out = tmp_path / "without"
    comparison.write_report(step_results, str(out))
    text = (out / "REPORT.md").read_text()
    assert "IAE / bound" not in text and "not part of this build" in text
    assert not any(r.get("bound_ratio") for r in csv.DictReader(open(out / "steps.csv")))
    calls = []

    def fake_bound(task, amplitude, *, t_step, t_end, plant, current_limit):
        calls.append((task, amplitude, t_step, t_end, current_limit))
        return SimpleNamespace(iae_bound=0.001 * abs(amplitude))

    monkeypatch.setattr(comparison, "bound_function", lambda: fake_bound)
    out = tmp_path / "with"
    comparison.write_report(step_results, str(out))
    assert sorted(set(calls)) == sorted({("velocity", a, STEP_TIME, STEP_SECONDS["velocity"], 10.0)
                                         for a in CFG.step_amplitudes})  # once per task and amplitude
    rows = list(csv.DictReader(open(out / "steps.csv")))
    assert len(rows) == 4
    for r in rows:
        assert float(r["bound_ratio"]) == pytest.approx(float(r["iae_r"]) / (0.001 * abs(float(r["amplitude"]))))
    text = (out / "REPORT.md").read_text()
    assert "IAE / bound" in text and "x the bound" in text and not math.isnan(float(rows[0]["bound_ratio"]))


def test_a_step_the_bound_refuses_gets_no_ratio_and_a_note(step_results, tmp_path, monkeypatch):
    def refusing(task, amplitude, **kw):
        if amplitude < 0:
            raise ValueError("amplitude must be one the current limit can hold")
        return SimpleNamespace(iae_bound=0.01)

    monkeypatch.setattr(comparison, "bound_function", lambda: refusing)
    out = tmp_path / "refused"
    comparison.write_report(step_results, str(out))
    rows = list(csv.DictReader(open(out / "steps.csv")))
    assert all(r["bound_ratio"] == "nan" for r in rows if float(r["amplitude"]) < 0)
    assert all(float(r["bound_ratio"]) > 0 for r in rows if float(r["amplitude"]) > 0)
    assert "velocity, step -1: no physical bound (amplitude must be one the current limit can hold)" in \
        (out / "REPORT.md").read_text()


def test_a_policy_of_an_earlier_loop_is_marked_in_the_step_table():
    """Its row is listed (its own settings), marked, not mixed in with today's laws unmarked."""
    old = ev.object_spec("old-loop", object.__new__(type("P", (), {"predict": lambda *a, **k: None})),
                         env_kwargs={"task": "velocity", "ref_accel": 0.0, "sigma": 1e4})
    row = {"suite": "step", "task": "velocity", "run": 0, "iae_r": 0.01, "diverged": False, "lost_track": False,
           "level": 0.5, "step_rise_time": 0.02, "step_overshoot": 1.0, "step_settling_time": 0.05}
    res = SimpleNamespace(specs=[ev.parse_policy("clf-n2"), old],
                          rows=[{**row, "policy": "clf-n2"}, {**row, "policy": "old-loop"}])
    rows = comparison.step_rows(res)
    assert [r["earlier_loop"] for r in rows] == [False, True]
    table = comparison.step_table(rows, False)
    assert [t[1] for t in table] == ["clf-n2", "old-loop (earlier loop)"]
    assert "old-loop (earlier loop) IAE" in comparison.step_lines(rows, False)[0]["line"]
