"""The step suite's physical bounds, kept once per case: the table shipped with the package holds every case of the
default suite and agrees with a fresh computation; the key changes with every input; a case not in the table is
computed once and then served from the job store."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest

from ehss_gym.core.params import PlantParams
from ehss_gym.infra.execution import Backend, Executor
from ehss_gym.study import bound_table as bt
from ehss_gym.study.bound import step_bound

# A fresh computation against the shipped table, relative. Measured across CPU code paths (tools/cpu_spread.py
# --workloads bounds, four cases of both tasks: numba, numpy, MKL, torch and OpenBLAS limited to AVX2, and glibc's
# libm without FMA): bitwise equal. The bound is a numerical optimum, though: arithmetic that sent the optimiser down
# another path would end where its stopping rule does (the last ten linear programs gaining less than 1e-5 of the
# IAE), hence 1e-4. A 1 % error in the current limit, the inertia or the valve gain moves a bound by 3.4e-3 (velocity
# +0.5 rad/s: measured), 34 times the tolerance.
REL_TOL = 1e-4
CHEAP = ("velocity", 0.5)  # the default case that costs least to compute (about 4 CPU-s)


def _default(task: str, amplitude: float) -> dict:
    return next(c for c in bt.default_cases() if c["task"] == task and c["amplitude"] == amplitude)


def test_every_case_of_the_default_step_suite_is_in_the_shipped_table():
    table = bt.shipped()
    cases = bt.default_cases()
    assert len(table) == len(cases) == 16
    for c in cases:
        entry = table.get(bt.case_key(c))
        assert entry is not None, f"{c['task']} {c['amplitude']:+g} is not in the table: run {bt.TABLE_COMMAND}"
        assert {k: entry[k] for k in ("task", "amplitude", "t_step", "t_end", "current_limit")} == \
            {k: c[k] for k in ("task", "amplitude", "t_step", "t_end", "current_limit")}
        assert entry["plant"] == c["plant"].as_dict()
        assert math.isfinite(entry["iae_bound"]) and entry["iae_bound"] > 0


def test_the_key_changes_with_every_input(monkeypatch):
    base = _default(*CHEAP)
    changed = [{**base, "plant": base["plant"].replace(J=base["plant"].J * (1 + 1e-12))},
               {**base, "current_limit": 9.99}, {**base, "amplitude": 0.5000001}, {**base, "t_step": 0.2},
               {**base, "t_end": 1.1}, {**base, "task": "position"}]
    keys = {bt.case_key(c) for c in [base] + changed}
    assert len(keys) == 1 + len(changed)
    key = bt.case_key(base)
    monkeypatch.setattr(bt, "BOUND_VERSION", bt.BOUND_VERSION + 1)  # a new algorithm: every case recomputed
    assert bt.case_key(base) != key


def _fresh_against_table(task: str, amplitude: float) -> float:
    c = _default(task, amplitude)
    fresh = step_bound(task, amplitude, t_step=c["t_step"], t_end=c["t_end"], plant=c["plant"],
                       current_limit=c["current_limit"]).iae_bound
    shipped = bt.shipped()[bt.case_key(c)]["iae_bound"]
    return abs(fresh - shipped) / shipped


def test_a_shipped_bound_is_what_a_fresh_computation_gives():
    assert _fresh_against_table(*CHEAP) <= REL_TOL


@pytest.mark.slow
@pytest.mark.parametrize("task, amplitude", [(c["task"], c["amplitude"]) for c in bt.default_cases()])
def test_every_shipped_bound_is_what_a_fresh_computation_gives(task, amplitude):
    assert _fresh_against_table(task, amplitude) <= REL_TOL


def test_a_case_not_in_the_table_is_computed_once_then_served_from_the_store(tmp_path, monkeypatch):
    """Another plant: computed as a job (the store keeps it), then a new process (emptied memory) reads the store."""
    calls = []

    def fake(task, amplitude, **kw):
        calls.append((task, amplitude, kw["plant"]))
        return SimpleNamespace(iae_bound=0.5 * abs(amplitude), t_reach=0.01)

    monkeypatch.setattr(bt, "step_bound", fake)
    monkeypatch.setattr(bt, "_KEPT", {})
    other = PlantParams().scaled(J=1.2)
    c = bt.case("velocity", 0.5, t_step=0.1, t_end=1.0, plant=other, current_limit=10.0)
    assert bt.case_key(c) not in bt.shipped()
    with Executor(Backend("local", workers=1), store=str(tmp_path / "jobs")) as ex:
        assert bt.prefetch([c, c], ex) == 1 and ex.computed == 1
    kept = bt.kept_step_bound("velocity", 0.5, t_step=0.1, t_end=1.0, plant=other)
    assert kept.iae_bound == 0.25 and kept.source == "kept" and len(calls) == 1
    monkeypatch.setattr(bt, "_KEPT", {})  # as in a new process
    with Executor(Backend("local", workers=1), store=str(tmp_path / "jobs")) as ex:
        assert bt.prefetch([c], ex) == 1 and ex.skipped == 1 and ex.computed == 0
    assert len(calls) == 1
    shipped = bt.kept_step_bound("velocity", 0.5, t_step=0.1, t_end=1.0)  # Table I: from the table, no job
    assert shipped.source == "table" and len(calls) == 1


def test_a_refused_case_keeps_its_reason(monkeypatch):
    def refusing(task, amplitude, **kw):
        raise ValueError("amplitude 9 rad/s cannot be held under the current limit")

    monkeypatch.setattr(bt, "step_bound", refusing)
    monkeypatch.setattr(bt, "_KEPT", {})
    for _ in range(2):  # the second time from what was kept
        with pytest.raises(ValueError, match="cannot be held"):
            bt.kept_step_bound("velocity", 9.0, t_step=0.1, t_end=1.0)
