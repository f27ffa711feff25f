"""The scripted compensators ``dcomp-n<k>`` and ``vinv-n<k>``: their per-task rows, the specs the evaluation runs, and
the sweep's rule that chose the rows (``tools/compensator_sweep.py``), on synthetic results and, marked slow, by
rerunning the sweep itself."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from ehss_gym.controllers import COMPENSATOR_ROWS, compensated_tasks, compensator_rows, parse_scripted
from ehss_gym.envs.config import EnvConfig
from ehss_gym.evaluation.specs import scripted_spec

_spec = importlib.util.spec_from_file_location(
    "compensator_sweep", Path(__file__).resolve().parents[1] / "tools" / "compensator_sweep.py")
sweep = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(sweep)

KEYS = {"dcomp": ("reference_delay",), "vinv": ("inverse_threshold", "inverse_hysteresis")}


@pytest.mark.parametrize("kind", ["dcomp", "vinv"])
@pytest.mark.parametrize("task", ["velocity", "position"])
def test_a_compensator_name_takes_its_tasks_row_and_the_env_accepts_it(kind, task):
    kw = parse_scripted(f"{kind}-n2", task)
    assert kw == {"n": 2, "mode": "residual", **COMPENSATOR_ROWS[kind][task]}
    assert set(COMPENSATOR_ROWS[kind][task]) == set(KEYS[kind])
    cfg = EnvConfig.from_kwargs({**kw, "task": task})
    assert all(getattr(cfg, k) == v for k, v in COMPENSATOR_ROWS[kind][task].items())
    # without a task: the env's default task's row (the env's default task is velocity)
    assert parse_scripted(f"{kind}-n4") == {"n": 4, "mode": "residual", **COMPENSATOR_ROWS[kind]["velocity"]}


def test_a_compensator_row_of_an_unknown_task_names_the_accepted_tasks():
    with pytest.raises(ValueError, match=r"task must be one of \['position', 'velocity'\], got 'angle'"):
        parse_scripted("dcomp-n2", "angle")
    assert parse_scripted("vinv-foh-n2") is None and parse_scripted("dcomp-n") is None


@pytest.mark.parametrize("kind", ["dcomp", "vinv"])
def test_the_evaluation_runs_a_compensator_where_it_compensates_with_that_tasks_row(kind):
    spec = scripted_spec(f"{kind}-n2")
    rows = compensator_rows(kind, ("velocity", "position"))
    on = tuple(t for t in ("velocity", "position") if any(rows[t].values()))
    assert spec.tasks == on == compensated_tasks(kind, ("velocity", "position")) and on
    for t in on:
        assert spec.env_kwargs_for(t) == {**spec.env_kwargs, **rows[t], "task": t}
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


@pytest.mark.slow
def test_the_shipped_rows_are_the_sweeps_choice():
    """Reruns ``python tools/compensator_sweep.py`` (48 training scenarios per task and compensator, about a minute on
    2 cores) and checks that its rule chooses the shipped rows."""
    for kind, cands in sweep.candidates().items():
        for task in sweep.TASKS:
            assert sweep.choose(sweep.sweep_task(task, cands, 48), cands) == COMPENSATOR_ROWS[kind][task], (kind, task)
