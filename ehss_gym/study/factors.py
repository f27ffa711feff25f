"""The factor table: does each metric class of the ruler see what it is meant to see?

The default law (the env's defaults, zero residual) on the held-out suite of each task, as it is and with one cause
removed at a time, and all together:

- ``no friction``: every friction event's amplitude set to 0, its window kept (the disturbance class is measured on
  the same samples);
- ``no mismatch``: the true plant set to the controller's model;
- ``no noise``: the sensor noise removed.

Per class the absolute level is the geometric mean over the class's episodes of the raw metric pair (not a ratio):
tracking sqrt(trk_rmse * trk_iae), disturbance sqrt(dst_peak * dst_iae), effort and chatter sqrt(tv_u_rate * rms_u)
(:mod:`ehss_gym.evaluation.scoring`, the ruler's physical floors included; the same with the numeric floors it had
before, to show what a cause moves that no instrument resolves). The class of an episode is fixed by the suite as it
is (effort: the episodes without sensor noise, chatter: those with it), so each column compares the same episodes.
The check written with the ruler, before any run: removing friction moves the disturbance class by 2x or more,
removing the noise moves the chatter class by 2x or more.

Also measured: the share of the pooled sum of e_t^2 (the true error, all episodes) that falls in the start-up,
t < 0.2 s, as it is.

**Which rankings the physical floors change** (:func:`rankings`): the scripted policies of ``ehss evaluate``
(:data:`~ehss_gym.evaluation.specs.SCRIPTED_DEFAULT`) on every suite it ranks (paper, held-out, robustness,
unmodelled), run once through the harness, their episodes scored by the ruler with the physical floors and with the
numeric ones; per (suite, task) and figure (overall and each class) the order of the policies under each, and where it
differs.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import replace

import numpy as np

from ehss_gym.core import layout
from ehss_gym.core.scenarios import PHYSICAL_FIELDS, heldout_scenarios
from ehss_gym.core.sim import Scenario, simulate_batch
from ehss_gym.envs import EnvConfig
from ehss_gym.evaluation.harness import evaluate
from ehss_gym.evaluation.scoring import (
    CLASS_METRICS,
    CLASSES,
    FIGURE_SUITES,
    NUMERIC_FLOORS,
    PHYSICAL_FLOORS,
    Block,
    Floors,
    episode_classes,
    failure,
    rank_key,
    ratio_rows,
)
from ehss_gym.evaluation.specs import SCRIPTED_DEFAULT, scripted_specs
from ehss_gym.evaluation.suites import TASKS, EvalConfig
from ehss_gym.infra.execution import Executor

PROG = "ehss factors"
FACTORS = ("as is", "no friction", "no mismatch", "no noise", "none of them")
CHECKS = (("no friction", "disturbance"), ("no noise", "chatter"))  # (factor removed, class it must move)
MOVE = 2.0  # [-] the check: the class moves by at least this factor
NO_NOISE = (0.0, 0.0, 0.0, 0.0)


# Each cause is removed by a function of an episode's physical fields (a mapping: ``Episode.physical``, or a
# Scenario's via :func:`physical`) returning the fields it changes; the scripted table here and the learned
# policies' (:mod:`ehss_gym.study.factors_learned`, through the harness) remove a cause with the same function.
def _no_friction(p: Mapping) -> dict:
    return {"friction": tuple((0.0, t0, t1) for _, t0, t1 in p["friction"])}


def _no_mismatch(p: Mapping) -> dict:
    return {"plant": p["model"] or p["plant"], "model": None}


def _no_noise(p: Mapping) -> dict:
    return {"noise_std": NO_NOISE}


def _no_valve(p: Mapping) -> dict:
    return {"unmodelled": replace(p["unmodelled"], threshold=0.0, hysteresis=0.0)}


def _no_delay(p: Mapping) -> dict:
    return {"unmodelled": replace(p["unmodelled"], delay=0)}


def _no_quantisation(p: Mapping) -> dict:
    return {"unmodelled": replace(p["unmodelled"], encoder_counts=0, velocity_step=0.0)}


# cause -> the function that removes it (the unmodelled groups: ehss_gym.core.unmodelled)
CAUSES = {"friction": _no_friction, "mismatch": _no_mismatch, "noise": _no_noise, "valve": _no_valve,
          "delay": _no_delay, "quantisation": _no_quantisation}
REMOVE = {"as is": (), "no friction": (_no_friction,), "no mismatch": (_no_mismatch,), "no noise": (_no_noise,),
          "none of them": (_no_friction, _no_mismatch, _no_noise)}


def physical(sc: Scenario) -> dict:
    """A scenario's physical fields (:data:`ehss_gym.core.scenarios.PHYSICAL_FIELDS`)."""
    return {f: getattr(sc, f) for f in PHYSICAL_FIELDS}


def removed(p: Mapping, fns: Sequence) -> dict:
    """Physical fields ``p`` with each cause of ``fns`` (functions of :data:`CAUSES`) removed, in order."""
    out = dict(p)
    for fn in fns:
        out.update(fn(out))
    return out


def variants(scenarios: Sequence[Scenario]) -> dict[str, list[Scenario]]:
    """Factor -> the scenarios with that cause (or all of them) removed."""
    return {name: [sc.replace(**removed(physical(sc), REMOVE[name])) for sc in scenarios] for name in FACTORS}


def class_level(metrics: Sequence[dict], cls: str, task: str, floors: Floors = PHYSICAL_FLOORS) -> float:
    """The geometric mean over episodes of sqrt(a * b), the class's raw metric pair floored (``floors``, the ruler's
    by default, for ``task``); NaN if none."""
    logs = []
    for m in metrics:
        v = 0.0
        for key in CLASS_METRICS[cls]:
            x = m[key]
            if not math.isfinite(x):
                break
            v += 0.5 * math.log(max(x, floors.of(key, task, m)))
        else:
            logs.append(v)
    return math.exp(float(np.mean(logs))) if logs else math.nan


def startup_share(trajs) -> float:
    """The share of the pooled sum of the true error's squares in the start-up window (t < 0.2 s)."""
    su = sum(float(t.acc[layout.M_SU_SUM_E2]) for t in trajs)
    total = sum(float(t.acc[layout.M_SUM_E2_TRUE]) for t in trajs)
    return su / total if total > 0 else math.nan


def _level_rows(ms: dict, member: dict, task: str, floors: Floors) -> list[dict]:
    """Per factor the class levels (floored at ``floors``) and their ratios to the suite as it is."""
    rows = []
    for name in FACTORS:
        rows.append({"factor": name, **{c: class_level([ms[name][i] for i in member[c]], c, task, floors)
                                        for c in CLASSES}})
    for row in rows:
        for c in CLASSES:
            row[f"{c}_ratio"] = row[c] / rows[0][c] if rows[0][c] > 0 else math.nan
    return rows


def task_factors(task: str, episodes: int, episode_seconds: float = 2.0) -> dict:
    """The factor table of one task: per factor the class levels and their ratio to the suite as it is, with the
    ruler's physical floors and with the numeric ones.

    Returns:
        {"task", "episodes", "used" (episodes no variant diverged on), "class_episodes" (per class), "rows" (one per
        factor: "factor", "<class>" level, "<class>_ratio", "<class>_numeric" and "<class>_numeric_ratio": the same
        with the numeric floors), "startup_share", "checks" (per check, with the physical floors: factor, class,
        ratio, met), "others" (every other single cause that moves a class by MOVE or more: factor, class, ratio),
        "floor_blind" (every single cause that moves a class by MOVE or more with the numeric floors but not with the
        physical ones: factor, class, numeric and physical ratios), "wall_s"}.
    """
    t0 = time.perf_counter()
    base = heldout_scenarios(episodes, EnvConfig.from_kwargs({"task": task}).template(), episode_seconds)
    runs = {name: simulate_batch(scs) for name, scs in variants(base).items()}
    ok = [i for i in range(len(base)) if not any(runs[f][i].diverged for f in FACTORS)]
    ms = {name: [t.metrics() for t in runs[name]] for name in FACTORS}
    # an episode's classes are the suite's as it is (its noise; a disturbance window it has)
    member = {c: [i for i in ok if c in episode_classes(any(v > 0 for v in base[i].noise_std))
                  and math.isfinite(class_level([ms["as is"][i]], c, task))] for c in CLASSES}
    rows = _level_rows(ms, member, task, PHYSICAL_FLOORS)
    for row, num in zip(rows, _level_rows(ms, member, task, NUMERIC_FLOORS)):
        row.update({f"{c}_numeric": num[c] for c in CLASSES})
        row.update({f"{c}_numeric_ratio": num[f"{c}_ratio"] for c in CLASSES})
    by = {r["factor"]: r for r in rows}
    checks = []
    for factor, cls in CHECKS:
        r = by[factor][f"{cls}_ratio"]
        moved = _moved(r)
        checks.append({"factor": factor, "class": cls, "ratio": r, "moved": moved, "met": moved >= MOVE})
    others = [{"factor": f, "class": c, "ratio": by[f][f"{c}_ratio"]} for f in FACTORS[1:-1] for c in CLASSES
              if (f, c) not in CHECKS and _moved(by[f][f"{c}_ratio"]) >= MOVE]
    blind = [{"factor": f, "class": c, "numeric": by[f][f"{c}_numeric_ratio"], "physical": by[f][f"{c}_ratio"]}
             for f in FACTORS[1:] for c in CLASSES
             if _moved(by[f][f"{c}_numeric_ratio"]) >= MOVE and not _moved(by[f][f"{c}_ratio"]) >= MOVE]
    return {"task": task, "episodes": len(base), "used": len(ok),
            "class_episodes": {c: len(member[c]) for c in CLASSES}, "rows": rows,
            "startup_share": startup_share(runs["as is"]), "checks": checks, "others": others,
            "floor_blind": blind, "wall_s": time.perf_counter() - t0}


RANK_SUITES = FIGURE_SUITES  # the suites whose rankings the report compares under both floors: every ranked suite


def _orders(rows: list, names: Sequence[str], suite: str, task: str) -> dict:
    """Per figure ("overall" and each class present) the policies in the ruler's order on one (suite, task), with
    their figures: {figure: [(policy, G), ...]} (the overall order with the failure gate first, as the harness ranks;
    a class's by its figure)."""
    blk = Block(rows, names, suite, task)
    figs = {n: blk.figure(n) for n in names}
    gate = {n: failure([r for r in rows if r["policy"] == n and r["suite"] == suite and r["task"] == task])
            for n in names}
    out = {"overall": [(n, figs[n][0]) for n in sorted(names, key=lambda n: rank_key(*gate[n], figs[n][0], n))]}
    for c in blk.classes:
        have = [n for n in names if math.isfinite(figs[n][1].get(c, math.nan))]
        out[c] = [(n, figs[n][1][c]) for n in sorted(have, key=lambda n: (figs[n][1][c], n))]
    return out


def rankings(tasks: Sequence[str] = TASKS, episodes: int = 48, executor: Executor | None = None,
             progress: bool = False, quick: bool = False) -> list[dict]:
    """The scripted policies on every ranked suite, ranked with the numeric and the physical floors.

    Args:
        tasks: the tasks.
        episodes: held-out (and unmodelled-suite) episodes per task; the paper and robustness suites are
            ``ehss evaluate``'s.
        executor: where the episodes run (default: this machine's cores).
        progress: show a progress bar.
        quick: the CI form: a 2 s paper run, one friction and one mismatch level (numbers not meaningful).

    Returns:
        One dict per (suite, task): "suite", "task", "orders" ({"numeric": ..., "physical": ...}, each
        :func:`_orders`), "changed" (the figures whose order differs).
    """
    cfg = EvalConfig(suites=RANK_SUITES, tasks=tuple(tasks), heldout_episodes=episodes)
    if quick:
        cfg = EvalConfig.quick(suites=RANK_SUITES, tasks=tuple(tasks), heldout_episodes=episodes, paper_seconds=2.0,
                               friction_levels=(1.8,), mismatch_levels=(0.2,))
    specs = scripted_specs(SCRIPTED_DEFAULT, tasks)
    res = evaluate(specs, cfg, progress=progress, command=PROG, executor=executor)
    out = []
    for suite in RANK_SUITES:
        for task in tasks:
            names = [s.name for s in res.specs if task in s.tasks]  # a compensator acts on one task only
            orders = {}
            for floors in (NUMERIC_FLOORS, PHYSICAL_FLOORS):
                rows = [dict(r) for r in res.rows]
                ratio_rows(rows, floors)
                orders[floors.name] = _orders(rows, names, suite, task)
            changed = [f for f in orders["physical"]
                       if [n for n, _ in orders["physical"][f]] != [n for n, _ in orders["numeric"].get(f, [])]]
            out.append({"suite": suite, "task": task, "orders": orders, "changed": changed})
    return out


def _moved(ratio: float) -> float:
    """How far a ratio moved from 1, either way (>= 1; NaN for an undefined ratio)."""
    return max(ratio, 1.0 / ratio) if ratio > 0 else math.nan


def run(tasks: Sequence[str] = TASKS, episodes: int = 48, episode_seconds: float = 2.0) -> list[dict]:
    """:func:`task_factors` of every task."""
    return [task_factors(t, episodes, episode_seconds) for t in tasks]


__all__ = ["PROG", "FACTORS", "CAUSES", "physical", "removed",
           "CHECKS", "MOVE", "RANK_SUITES", "variants", "class_level", "startup_share",
           "task_factors", "rankings", "run"]
