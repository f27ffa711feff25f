"""The scripted compensators ``dcomp-n<k>``, ``vinv-n<k>`` and ``eso-n<k>``: their per-task rows (Table I's built in,
a plant's in its law table), the specs the evaluation runs, and the sweep's rule that chose the rows
(:mod:`ehss_gym.study.compensators`, the last stage of ``ehss baselines``), on synthetic results and, marked slow, by
rerunning the sweep itself."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from ehss_gym.controllers import (
    COMPENSATOR_ROWS,
    compensated_tasks,
    compensator_rows,
    compensator_settings,
    parse_scripted,
)
from ehss_gym.envs.config import EnvConfig
from ehss_gym.envs.law_table import LawSettingsError, load_law_table, table_from_dict
from ehss_gym.evaluation import EvalConfig, PolicyError
from ehss_gym.evaluation.harness import _check_tasks, _complete_specs
from ehss_gym.evaluation.specs import scripted_spec, scripted_specs
from ehss_gym.study import compensators as sweep

ROOT = Path(__file__).resolve().parents[1]
TASKS = ("velocity", "position")

KEYS = {"dcomp": ("reference_delay",), "vinv": ("inverse_threshold", "inverse_hysteresis"), "eso": ("observer_hz",)}
KINDS = tuple(KEYS)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("task", ["velocity", "position"])
def test_a_compensator_name_takes_its_tasks_row_and_the_env_accepts_it(kind, task):
    kw = parse_scripted(f"{kind}-n2", task)
    loop = compensator_settings(kind, COMPENSATOR_ROWS[kind][task])
    assert kw == {"n": 2, "mode": "residual", **loop}
    assert set(COMPENSATOR_ROWS[kind][task]) == set(KEYS[kind])
    cfg = EnvConfig.from_kwargs({**kw, "task": task})
    assert all(getattr(cfg, k) == v for k, v in loop.items())
    # without a task: the env's default task's row (the env's default task is velocity)
    velocity = compensator_settings(kind, COMPENSATOR_ROWS[kind]["velocity"])
    assert parse_scripted(f"{kind}-n4") == {"n": 4, "mode": "residual", **velocity}


def test_the_observers_row_is_the_estimator_at_its_bandwidth_and_zero_is_the_default_estimator():
    assert compensator_settings("eso", {"observer_hz": 200.0}) == {"estimator": "eso", "observer_hz": 200.0}
    assert compensator_settings("eso", {"observer_hz": 0.0}) == {}
    assert compensator_settings("vinv", {"inverse_threshold": 0.25, "inverse_hysteresis": 1.5}) == {
        "inverse_threshold": 0.25, "inverse_hysteresis": 1.5}
    # the env takes it: the velocity task's default estimator is the state-variable filter, the row switches it
    cfg = EnvConfig.from_kwargs({"task": "velocity", **compensator_settings("eso", {"observer_hz": 100.0})})
    assert cfg.estimator == "eso" and cfg.observer_hz == 100.0
    assert EnvConfig.from_kwargs({"task": "velocity"}).estimator != "eso"


def test_a_compensator_row_of_an_unknown_task_names_the_accepted_tasks():
    with pytest.raises(ValueError, match=r"task must be one of \['position', 'velocity'\], got 'angle'"):
        parse_scripted("dcomp-n2", "angle")
    assert parse_scripted("vinv-foh-n2") is None and parse_scripted("dcomp-n") is None


@pytest.mark.parametrize("kind", KINDS)
def test_the_evaluation_runs_a_compensator_where_it_compensates_with_that_tasks_row(kind):
    spec = scripted_spec(f"{kind}-n2")
    rows = compensator_rows(kind, ("velocity", "position"))
    on = tuple(t for t in ("velocity", "position") if any(rows[t].values()))
    assert spec.tasks == on == compensated_tasks(kind, ("velocity", "position")) and on
    for t in on:
        assert spec.env_kwargs_for(t) == {**spec.env_kwargs, **compensator_settings(kind, rows[t]), "task": t}
        assert f"({t})" in spec.source
    # a caller's own size replaces the rows: then it runs on both tasks at that size
    own = scripted_spec(f"{kind}-n2", label="mine", env_overrides={KEYS[kind][0]: 0.5})
    assert own.tasks == ("velocity", "position") and own.task_kwargs == {}
    assert all(own.env_kwargs_for(t)[KEYS[kind][0]] == 0.5 for t in own.tasks)


def _result(figure, failed=False):
    return {"figure": figure, "failed": failed}


def test_the_sweeps_rule_per_task_failure_first_then_the_lowest_then_the_smallest_within_one_percent():
    cands = [{"reference_delay": d} for d in (0.0, 1.0, 2.0, 3.0)]
    # the lowest (2) failed; 1 is the lowest admissible, 3 within 1 % of it but larger: 1
    assert sweep.choose([_result(1.0), _result(0.80), _result(0.5, True), _result(0.795)], cands) == cands[1]
    # none within 1 % but the lowest: the lowest, however large
    assert sweep.choose([_result(1.0), _result(0.9), _result(0.7), _result(0.8)], cands) == cands[2]
    # the uncompensated law within 1 % of the best: no compensation
    assert sweep.choose([_result(1.0), _result(0.995), _result(0.991), _result(1.2)], cands) == cands[0]
    inv = sweep.candidates()["vinv"]
    ties = [_result(0.9 if c["inverse_threshold"] + c["inverse_hysteresis"] >= 3.0 else 1.0) for c in inv]
    # the smallest threshold + hysteresis among the tied, then the smallest threshold
    assert sweep.choose(ties, inv) == {"inverse_threshold": 0.0, "inverse_hysteresis": 3.0}


def test_the_observers_tie_goes_to_the_default_estimator_then_to_the_highest_bandwidth():
    eso = sweep.candidates()["eso"]
    assert eso[0] == {"observer_hz": 0.0} and all(c["observer_hz"] > 0.0 for c in eso[1:])
    assert all(sweep.kind_of(c) == "eso" for c in eso) and sweep.kind_of({"reference_delay": 1.0}) == "dcomp"
    hz = [c["observer_hz"] for c in eso]
    # every observer within 1 % of "off": off
    assert sweep.choose([_result(1.0)] + [_result(0.995)] * (len(eso) - 1), eso) == eso[0]
    # the observers tied, "off" far behind: the highest bandwidth among the tied
    res = [_result(1.0)] + [_result(0.20 if f <= 200.0 else 0.30) for f in hz[1:]]
    assert sweep.choose(res, eso) == {"observer_hz": 200.0}


@pytest.mark.slow
def test_the_shipped_rows_are_the_sweeps_choice():
    """Reruns the sweep on Table I's built-in laws (48 training scenarios per task and compensator, about 30 s) and
    checks that its rule chooses the shipped rows."""
    for kind, cands in sweep.candidates().items():
        for task in TASKS:
            got = sweep.choose(sweep.sweep_task(task, cands, 48, 2.0), cands)
            assert got == COMPENSATOR_ROWS[kind][task], (kind, task)


def test_table_is_built_in_rows_are_the_shipped_baselines_reports():
    """The built-in rows are what ``ehss baselines`` wrote for Table I (reports/baselines/law_settings.json)."""
    table = load_law_table(ROOT / "reports" / "baselines" / "law_settings.json")
    for kind in COMPENSATOR_ROWS:
        assert compensator_rows(kind, TASKS, table) == COMPENSATOR_ROWS[kind], kind


def _table(rows: dict | None) -> dict:
    """A law-settings dict on Table I's n = 2 law with the compensator rows ``rows`` (task -> {"dcomp-n2": ...})."""
    law = {"sigma": 1e5, "fr": 60.0, "smoothing": 100.0, "layer_gain": 3.0}
    return {"plant": {"label": "test rig", "hash": "0"},
            **{t: {"default_n": 2, "clf-n2": law, **((rows or {}).get(t, {}))} for t in TASKS}}


PLANT_ROWS = {"velocity": {"dcomp-n2": {"reference_delay": 1.5},
                           "vinv-n2": {"inverse_threshold": 0.0, "inverse_hysteresis": 0.0},
                           "eso-n2": {"observer_hz": 100.0}},
              "position": {"dcomp-n2": {"reference_delay": 2.0},
                           "vinv-n2": {"inverse_threshold": 0.25, "inverse_hysteresis": 1.5},
                           "eso-n2": {"observer_hz": 0.0}}}


def test_a_law_table_carries_the_compensators_rows_and_names_a_bad_value():
    table = table_from_dict(_table(PLANT_ROWS))
    assert table.tasks["position"].compensators == {"dcomp": {"reference_delay": 2.0},
                                                     "vinv": {"inverse_threshold": 0.25, "inverse_hysteresis": 1.5},
                                                     "eso": {"observer_hz": 0.0}}
    assert table_from_dict(table.as_dict()) == table  # the file's content round-trips
    assert json.loads(json.dumps(table.as_dict()))["velocity"]["dcomp-n2"] == {"reference_delay": 1.5}
    bad = _table({"velocity": {"dcomp-n2": {"reference_delay": -1.0}}})
    with pytest.raises(LawSettingsError, match=r"velocity\.dcomp-n2\.reference_delay \[control samples\] must be"):
        table_from_dict(bad)
    with pytest.raises(LawSettingsError, match=r"unknown key\(s\) \['delay'\]"):
        table_from_dict(_table({"position": {"vinv-n2": {"delay": 1.0}}}))
    with pytest.raises(LawSettingsError, match="unknown key 'dcomp-n4'"):
        table_from_dict(_table({"position": {"dcomp-n4": {"reference_delay": 1.0}}}))


def test_a_plants_law_table_sets_a_compensators_rows_and_tasks():
    table = table_from_dict(_table(PLANT_ROWS))
    assert parse_scripted("dcomp-n2", "velocity", table)["reference_delay"] == 1.5
    spec = scripted_spec("dcomp-n2", laws=table)  # Table I's rows act on position only; this plant's on both
    assert spec.tasks == TASKS and spec.env_kwargs_for("velocity")["reference_delay"] == 1.5
    assert spec.env_kwargs_for("position")["reference_delay"] == 2.0 and "test rig" in spec.source
    vinv = scripted_spec("vinv-n2", laws=table)  # the plant's rule chose none in velocity
    assert vinv.tasks == ("position",) and vinv.env_kwargs_for("position")["inverse_threshold"] == 0.25
    assert [s.name for s in scripted_specs(("clf-n2", "vinv-n2"), ("velocity",), table)] == ["clf-n2"]
    eso = scripted_spec("eso-n2", laws=table)  # the observer chosen in velocity only
    assert eso.tasks == ("velocity",) and "100 Hz" in eso.source
    assert eso.env_kwargs_for("velocity")["estimator"] == "eso" and eso.env_kwargs_for("velocity")["observer_hz"] == 100
    with pytest.raises(LawSettingsError, match=r"position\.eso-n2\.observer_hz \[Hz\] must be"):
        table_from_dict(_table({"position": {"eso-n2": {"observer_hz": -5.0}}}))
    # the evaluation applies its law table to a spec named without it (--policies dcomp-n2 --law-settings FILE)
    cfg = EvalConfig(law_settings=table)
    done = _complete_specs([scripted_spec("clf-n2"), scripted_spec("dcomp-n2", label="mine")], cfg, [])
    assert done[1].name == "mine" and done[1].tasks == TASKS
    assert done[1].env_kwargs_for("velocity")["reference_delay"] == 1.5
    assert done[1].env_kwargs_for("velocity")["law_settings"] is table  # and still runs on the table's laws


def test_a_law_table_without_compensator_rows_runs_none_and_says_why():
    """A table of an earlier release has no compensator rows: Table I's are not used on its plant."""
    table = table_from_dict(_table(None))
    assert compensator_rows("dcomp", TASKS, table) == {}
    with pytest.raises(ValueError, match="no dcomp-n2 row for task 'position'; ehss baselines writes it"):
        parse_scripted("dcomp-n2", "position", table)
    cfg = EvalConfig(law_settings=table)
    specs = _complete_specs([scripted_spec("clf-n2"), scripted_spec("dcomp-n2")], cfg, [])
    assert specs[1].tasks == ()
    notes: list = []
    _check_tasks(specs, cfg, set(), notes)  # a default policy: skipped with a note
    assert any("dcomp-n2 acts on no task" in n for n in notes)
    with pytest.raises(PolicyError, match="acts on no task.*rerun ehss baselines"):
        _check_tasks(specs, cfg, {"dcomp-n2"}, [])


def test_a_residual_on_a_scripted_baselines_loop_is_in_todays_loop_and_another_estimator_is_not():
    """A learned policy on top of ``eso-n2`` (the velocity law with the observer at its row's bandwidth) is ranked
    with today's laws, as one on top of a compensator is; the observer at another bandwidth, or the paper's filter at
    another cutoff, is a loop of its own (an earlier one): not ranked."""
    from ehss_gym.evaluation.scoring import is_earlier_loop
    from ehss_gym.evaluation.specs import PolicySpec

    def learned(**kw):
        return PolicySpec(name="r", kind="object", runs=[object()], env_kwargs={"n": 2, "mode": "residual", **kw})

    row = compensator_settings("eso", COMPENSATOR_ROWS["eso"]["velocity"])
    assert row  # Table I's rule chose the observer in velocity
    assert not is_earlier_loop(learned(), "velocity")
    assert not is_earlier_loop(learned(**row), "velocity")
    assert not is_earlier_loop(learned(reference_delay=1.0), "position")  # an add-on: today's loop
    assert is_earlier_loop(learned(estimator="eso", observer_hz=2 * row["observer_hz"]), "velocity")
    assert is_earlier_loop(learned(estimator_hz=500.0), "velocity")
