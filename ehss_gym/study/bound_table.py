"""The physical bounds of the evaluation's step suite, computed once per distinct case and kept.

A step's bound (:func:`ehss_gym.study.bound.step_bound`) depends only on its inputs (the plant's values, the
current limit, the task, the amplitude, the step time, the end of the window, the control grid, the integrator's
step and the optimiser's settings) and on the algorithm, whose version is :data:`BOUND_VERSION`. Each case is keyed
by a SHA-256 of all of them (:func:`case_key`), and its bound is taken from, in order:

1. the table shipped with the package (``step_bounds.json``: every case of the default step suite, on the plant of
   Table I; made by ``python -m ehss_gym.study.bound_table --write`` and checked against a fresh computation by
   ``tests/test_bound_table.py``);
2. the bounds this process has already computed or read from a store;
3. a computation, as a job of the execution layer (:func:`prefetch`: the cases in parallel over the workers, each
   result kept in the job store when the executor has one, so a later run with the same store does not compute it
   again).

A case that is not in the table (another plant, limit, step or time) costs its computation once: from seconds to a
minute per step on one core.
"""

from __future__ import annotations

import argparse
import functools
import hashlib
import inspect
import json
import math
import pathlib
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass

from ehss_gym.core.params import PlantParams
from ehss_gym.envs.config import EnvConfig
from ehss_gym.evaluation.suites import STEP_AMPLITUDES, STEP_SECONDS, STEP_TIME, TASKS
from ehss_gym.infra.execution import Backend, Executor, Job, canonical
from ehss_gym.infra.util import atomic_write_text

from . import bound
from .bound import step_bound

# the algorithm's version: raise it when a change to the optimiser, its settings or the plant's equations moves the
# bounds (the key changes, so every kept bound is recomputed and the shipped table must be remade)
BOUND_VERSION = 1
TABLE_PATH = pathlib.Path(__file__).with_name("step_bounds.json")
TABLE_COMMAND = "python -m ehss_gym.study.bound_table --write"
CASE_FIELDS = ("task", "amplitude", "t_step", "t_end", "plant", "current_limit")


@dataclass(frozen=True)
class KeptBound:
    """A step's bound as kept: its IAE [output unit * s] and where it came from ("table", "kept" or "computed")."""

    iae_bound: float
    key: str
    source: str


def case(task: str, amplitude: float, *, t_step: float, t_end: float, plant: PlantParams | None = None,
         current_limit: float = 10.0) -> dict:
    """One step case as plain data (the job's config): task, amplitude [output unit], t_step and t_end [s], plant
    (default Table I) and current limit [mA]."""
    return {"task": task, "amplitude": float(amplitude), "t_step": float(t_step), "t_end": float(t_end),
            "plant": PlantParams() if plant is None else plant, "current_limit": float(current_limit)}


def case_key(c: dict) -> str:
    """SHA-256 of every input of the case's bound (:func:`ehss_gym.study.bound.bound_inputs`, the optimiser's
    defaults included) and :data:`BOUND_VERSION`. ValueError for a case the bound refuses."""
    args = inspect.signature(bound.step_bound).bind(c["task"], c["amplitude"], t_step=c["t_step"], t_end=c["t_end"],
                                              plant=c["plant"], current_limit=c["current_limit"])
    args.apply_defaults()
    inputs = bound.bound_inputs(*args.arguments.values())
    blob = json.dumps(["step_bound", BOUND_VERSION, canonical(inputs)], sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(blob.encode()).hexdigest()


def default_cases() -> list[dict]:
    """Every case of the default step suite: each task and amplitude, on Table I's plant at the env's limit."""
    return [case(task, a, t_step=STEP_TIME, t_end=STEP_SECONDS[task], plant=PlantParams(),
                 current_limit=EnvConfig.from_kwargs({"task": task}).current_limit)
            for task in TASKS for a in STEP_AMPLITUDES]


@functools.cache
def shipped() -> dict:
    """The shipped table: key -> entry (the case's inputs, ``iae_bound`` or ``error``)."""
    if not TABLE_PATH.is_file():
        return {}
    return json.loads(TABLE_PATH.read_text(encoding="utf-8"))["bounds"]


_KEPT: dict = {}  # this process's bounds beyond the table: key -> entry


def bound_job(config: dict, seed: int, context) -> dict:
    """A job of the execution layer: the bound of one case (``config``: :func:`case`), as plain data:
    ``iae_bound`` [output unit * s] and the reach time ``t_reach`` [s], or ``error`` (what the bound refuses, e.g. a
    velocity the limit cannot hold)."""
    try:
        b = step_bound(config["task"], config["amplitude"], t_step=config["t_step"], t_end=config["t_end"],
                       plant=config["plant"], current_limit=config["current_limit"])
    except ValueError as exc:
        return {"error": str(exc)}
    return {"iae_bound": b.iae_bound, "t_reach": b.t_reach}


def _entry(key: str) -> tuple[dict | None, str]:
    if key in shipped():
        return shipped()[key], "table"
    return _KEPT.get(key), "kept"


def prefetch(cases: Sequence[dict], executor: Executor | None = None, progress: bool = False) -> int:
    """Compute the bounds of ``cases`` that are neither in the table nor kept here, as jobs of ``executor`` (default:
    this machine's cores, no store); returns how many were not already known. Cases the bound refuses are kept with
    their error."""
    todo = {}
    for c in cases:
        key = case_key(c)
        if _entry(key)[0] is None:
            todo[key] = c
    if not todo:
        return 0
    _KEPT.update(zip(todo, _compute(list(todo.values()), executor, progress)))
    return len(todo)


def _compute(cases: Sequence[dict], executor: Executor | None, progress: bool) -> list:
    """The bound of each case, computed as jobs of ``executor`` (a local one of its own when None)."""
    jobs = [Job(bound_job, c, 0, label=f"bound {c['task']} {c['amplitude']:+g}") for c in cases]
    own = executor is None
    executor = executor or Executor(progress=progress)
    try:
        return executor.map(jobs, desc="step bounds")
    finally:
        if own:
            executor.close()


def kept_step_bound(task: str, amplitude: float, *, t_step: float, t_end: float, plant: PlantParams | None = None,
                    current_limit: float = 10.0) -> KeptBound:
    """The bound of one step from the table, or as kept, or computed now (in this process).

    Args:
        task, amplitude, t_step, t_end, plant, current_limit: as :func:`ehss_gym.study.bound.step_bound`'s.

    Raises:
        ValueError: a case the bound refuses (the bound's own message).
    """
    c = case(task, amplitude, t_step=t_step, t_end=t_end, plant=plant, current_limit=current_limit)
    key = case_key(c)
    entry, source = _entry(key)
    if entry is None:
        entry, source = bound_job(c, 0, None), "computed"
        _KEPT[key] = entry
    if "error" in entry:
        raise ValueError(entry["error"])
    return KeptBound(float(entry["iae_bound"]), key, source)


def table(cases: Sequence[dict], executor: Executor | None = None) -> dict:
    """The table of ``cases`` computed afresh (never read from the shipped one): its JSON document."""
    results = _compute(cases, executor, True)
    bounds = {}
    for c, r in zip(cases, results):
        inputs = {**c, "plant": c["plant"].as_dict()}
        bounds[case_key(c)] = {**inputs, **r}
    return {"made_by": TABLE_COMMAND, "version": BOUND_VERSION, "bounds": bounds}


def write_table(doc: dict, path: pathlib.Path = TABLE_PATH) -> None:
    """Write the table's JSON (floats exact: ``repr``)."""
    atomic_write_text(str(path), json.dumps(doc, indent=1, allow_nan=True) + "\n")


def main(argv=None) -> int:
    """``python -m ehss_gym.study.bound_table --write``: compute the default step suite's bounds and write the table
    shipped with the package; without ``--write``, compare a fresh computation with it (exit 1 on any difference)."""
    ap = argparse.ArgumentParser(prog="python -m ehss_gym.study.bound_table", description=main.__doc__)
    ap.add_argument("--write", action="store_true", help=f"write {TABLE_PATH.name}")
    ap.add_argument("--workers", type=int, default=None, help="worker processes (default: the cores)")
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    with Executor(Backend("local", workers=a.workers), progress=True) as ex:
        doc = table(default_cases(), ex)
    print(f"{len(doc['bounds'])} bounds in {time.perf_counter() - t0:.1f} s")
    old = shipped()
    worst = 0.0
    for key, e in doc["bounds"].items():
        was = old.get(key, {}).get("iae_bound", math.nan)
        now = e.get("iae_bound", math.nan)
        rel = abs(now - was) / abs(was) if math.isfinite(was) and math.isfinite(now) else math.inf
        worst = max(worst, rel) if key in old else math.inf
        print(f"{e['task']:8s} {e['amplitude']:+5g}: {now!r} (table: {was!r}, rel {rel:.3g})")
    if a.write:
        write_table(doc)
        print(f"wrote {TABLE_PATH}")
        return 0
    return 0 if worst == 0.0 else 1


__all__ = ["BOUND_VERSION", "TABLE_PATH", "KeptBound", "case", "case_key", "default_cases", "shipped", "bound_job",
           "prefetch", "kept_step_bound", "table", "write_table"]


if __name__ == "__main__":
    sys.exit(main())
