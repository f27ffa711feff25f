"""The factor table: does each metric class of the ruler see what it is meant to see?

The default law (the env's defaults, zero residual) on the held-out suite of each task, as it is and with one cause
removed at a time, and all together:

- ``no friction``: every friction event's amplitude set to 0, its window kept (the disturbance class is measured on
  the same samples);
- ``no mismatch``: the true plant set to the controller's model;
- ``no noise``: the sensor noise removed.

Per class the absolute level is the geometric mean over the class's episodes of the raw metric pair (not a ratio):
tracking sqrt(trk_rmse * trk_iae), disturbance sqrt(dst_peak * dst_iae), effort and chatter sqrt(tv_u_rate * rms_u)
(:mod:`ehss_gym.evaluation.scoring`, floors included). The class of an episode is fixed by the suite as it is (effort:
the episodes without sensor noise, chatter: those with it), so each column compares the same episodes. The check
written with the ruler, before any run: removing friction moves the disturbance class by 2x or more, removing the
noise moves the chatter class by 2x or more.

Also measured: the share of the pooled sum of e_t^2 (the true error, all episodes) that falls in the start-up,
t < 0.2 s, as it is.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence

import numpy as np

from ehss_gym.core import layout
from ehss_gym.core.scenarios import heldout_scenarios
from ehss_gym.core.sim import Scenario, simulate_batch
from ehss_gym.envs import EnvConfig
from ehss_gym.evaluation.scoring import CLASS_METRICS, CLASSES, episode_classes
from ehss_gym.evaluation.suites import TASKS

PROG = "ehss factors"
FACTORS = ("as is", "no friction", "no mismatch", "no noise", "none of them")
CHECKS = (("no friction", "disturbance"), ("no noise", "chatter"))  # (factor removed, class it must move)
MOVE = 2.0  # [-] the check: the class moves by at least this factor
NO_NOISE = (0.0, 0.0, 0.0, 0.0)


def _no_friction(sc: Scenario) -> Scenario:
    return sc.replace(friction=tuple((0.0, t0, t1) for _, t0, t1 in sc.friction))


def _no_mismatch(sc: Scenario) -> Scenario:
    return sc.replace(plant=sc.model or sc.plant, model=None)


def _no_noise(sc: Scenario) -> Scenario:
    return sc.replace(noise_std=NO_NOISE)


REMOVE = {"as is": (), "no friction": (_no_friction,), "no mismatch": (_no_mismatch,), "no noise": (_no_noise,),
          "none of them": (_no_friction, _no_mismatch, _no_noise)}


def variants(scenarios: Sequence[Scenario]) -> dict[str, list[Scenario]]:
    """Factor -> the scenarios with that cause (or all of them) removed."""
    out = {}
    for name in FACTORS:
        scs = list(scenarios)
        for fn in REMOVE[name]:
            scs = [fn(sc) for sc in scs]
        out[name] = scs
    return out


def class_level(metrics: Sequence[dict], cls: str) -> float:
    """The geometric mean over episodes of sqrt(a * b), the class's raw metric pair floored; NaN if none."""
    logs = []
    for m in metrics:
        v = 0.0
        for key, floor in CLASS_METRICS[cls]:
            x = m[key]
            if not math.isfinite(x):
                break
            v += 0.5 * math.log(max(x, floor))
        else:
            logs.append(v)
    return math.exp(float(np.mean(logs))) if logs else math.nan


def startup_share(trajs) -> float:
    """The share of the pooled sum of the true error's squares in the start-up window (t < 0.2 s)."""
    su = sum(float(t.acc[layout.M_SU_SUM_E2]) for t in trajs)
    total = sum(float(t.acc[layout.M_SUM_E2_TRUE]) for t in trajs)
    return su / total if total > 0 else math.nan


def task_factors(task: str, episodes: int, episode_seconds: float = 2.0) -> dict:
    """The factor table of one task: per factor the class levels and their ratio to the suite as it is.

    Returns:
        {"task", "episodes", "used" (episodes no variant diverged on), "class_episodes" (per class), "rows" (one per
        factor: "factor", "<class>" level, "<class>_ratio"), "startup_share", "checks" (per check: factor, class,
        ratio, met), "others" (every other single cause that moves a class by MOVE or more: factor, class, ratio),
        "wall_s"}.
    """
    t0 = time.perf_counter()
    base = heldout_scenarios(episodes, EnvConfig.from_kwargs({"task": task}).template(), episode_seconds)
    runs = {name: simulate_batch(scs) for name, scs in variants(base).items()}
    ok = [i for i in range(len(base)) if not any(runs[f][i].diverged for f in FACTORS)]
    ms = {name: [t.metrics() for t in runs[name]] for name in FACTORS}
    # an episode's classes are the suite's as it is (its noise; a disturbance window it has)
    member = {c: [i for i in ok if c in episode_classes(any(v > 0 for v in base[i].noise_std))
                  and math.isfinite(class_level([ms["as is"][i]], c))] for c in CLASSES}
    rows = []
    for name in FACTORS:
        row = {"factor": name}
        for c in CLASSES:
            row[c] = class_level([ms[name][i] for i in member[c]], c)
        rows.append(row)
    for row in rows:
        for c in CLASSES:
            row[f"{c}_ratio"] = row[c] / rows[0][c] if rows[0][c] > 0 else math.nan
    by = {r["factor"]: r for r in rows}
    checks = []
    for factor, cls in CHECKS:
        r = by[factor][f"{cls}_ratio"]
        moved = _moved(r)
        checks.append({"factor": factor, "class": cls, "ratio": r, "moved": moved, "met": moved >= MOVE})
    others = [{"factor": f, "class": c, "ratio": by[f][f"{c}_ratio"]} for f in FACTORS[1:-1] for c in CLASSES
              if (f, c) not in CHECKS and _moved(by[f][f"{c}_ratio"]) >= MOVE]
    return {"task": task, "episodes": len(base), "used": len(ok),
            "class_episodes": {c: len(member[c]) for c in CLASSES}, "rows": rows,
            "startup_share": startup_share(runs["as is"]), "checks": checks, "others": others,
            "wall_s": time.perf_counter() - t0}


def _moved(ratio: float) -> float:
    """How far a ratio moved from 1, either way (>= 1; NaN for an undefined ratio)."""
    return max(ratio, 1.0 / ratio) if ratio > 0 else math.nan


def run(tasks: Sequence[str] = TASKS, episodes: int = 48, episode_seconds: float = 2.0) -> list[dict]:
    """:func:`task_factors` of every task."""
    return [task_factors(t, episodes, episode_seconds) for t in tasks]


__all__ = ["PROG", "FACTORS", "CHECKS", "MOVE", "variants", "class_level", "startup_share", "task_factors", "run"]
