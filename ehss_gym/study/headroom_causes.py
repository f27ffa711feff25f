"""Where the unmodelled suite's headroom figures come from (``ehss headroom --causes``): each cause removed in turn.

The headroom table ranks oracles on the unmodelled suite by the ruler's overall figure against the base law. Before
such a figure ranks anything, it is split by cause: the suite's episodes (those of :mod:`ehss_gym.study.headroom`,
``--episodes`` of them per task) run as they are and with one cause removed at a time, the same causes and the same
functions as ``ehss factors --learned`` (:data:`ehss_gym.study.factors_learned.SUITE_CAUSES`: friction, the
plant-model mismatch, sensor noise, the valve's threshold and hysteresis, the sensor delay, quantisation). Every
variant of :data:`VARIANTS` runs every version of the episodes, the base law included, so each figure is still a
ratio on identical episodes; an oracle that knows an effect knows it as the episode has it (with the delay removed,
"delay known" compensates a delay of 0 samples, i.e. it is the base law).

**The rule** is ``ehss factors --learned``'s (:func:`ehss_gym.study.factors_learned.verdict`, written before its
runs): a figure within 2 % of 1 is level with the base law; otherwise its gain is *explained by* a cause if removing
that cause takes it within 2 % of 1 or across 1, *mostly* due to a cause if removing it takes away at least half of
its log, and a cause whose removal widens the gap by more than 2 % *works for* it. What the check shows for an
oracle that compensates an effect: if its figure does not move toward 1 when that effect is removed, the figure
measures something else than the compensation.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import replace

from ehss_gym.evaluation.scoring import physical_floors, ratio_rows
from ehss_gym.infra.execution import Executor, Job

from .factors import CAUSES, removed
from .factors_learned import AS_IS, SUITE_CAUSES, variant_names, verdict
from .headroom import (
    PROG,
    VARIANT_BY_NAME,
    HeadroomConfig,
    block_stats,
    episode_rows,
    row_meta,
    suite_episodes,
    variant_config,
    variant_job,
)

SUITE = "unmodelled"  # the suite split by cause
# the variants run on every version of the episodes: the reference law, the four scripted residuals, the oracles that
# know the unmodelled effects (with the valve's and both compensations, run by "delay known") and the best width with
# and without the known effects (the rows the headroom table's overall figure comes from on this suite)
VARIANTS = ("base law", "dob-n2", "dcomp-n2", "vinv-n2", "eso-n2", "best width", "delay known",
            "delay known, best width", "both known, best width")
SEP = "|"  # a version's suite label: "unmodelled|no delay"


def versions(causes: Sequence[str] | None = None) -> tuple[str, ...]:
    """The versions of the suite's episodes: as is, then each cause removed ("no <cause>"); ``causes`` a subset of
    the suite's causes (None: all of them).

    Raises:
        ValueError: a cause the suite does not have.
    """
    every = variant_names(SUITE)
    if causes is None:
        return every
    bad = sorted(set(causes) - set(SUITE_CAUSES[SUITE]))
    if bad:
        raise ValueError(f"causes must be a subset of {list(SUITE_CAUSES[SUITE])}, got {bad}")
    return tuple(v for v in every if v == AS_IS or v[3:] in causes)


def version_episodes(eps: list, version: str) -> list:
    """``eps`` with the cause of ``version`` removed (as they are for :data:`AS_IS`)."""
    fns = () if version == AS_IS else (CAUSES[version[3:]],)
    return [replace(ep, physical=removed(ep.physical, fns)) for ep in eps]


def plan(cfg: HeadroomConfig, causes: Sequence[str] | None = None) -> list[Job]:
    """Every job: per task, version of the episodes (:func:`versions` of ``causes``) and variant of :data:`VARIANTS`,
    at the variant's first agent period (the env's default for the base law and the scripted residuals, the free
    period for the oracles)."""
    jobs = []
    for task in cfg.tasks:
        eps = suite_episodes(cfg, task).get(SUITE)
        if not eps:
            continue
        for version in versions(causes):
            here = version_episodes(eps, version)
            for v in (VARIANT_BY_NAME[n] for n in VARIANTS):
                ap = cfg.periods_of(v, SUITE)[0]
                config = variant_config(cfg, v, task, f"{SUITE}{SEP}{version}", here, ap, env_suite=SUITE)
                jobs.append(Job(variant_job, config, seed=0, label=f"{task}/{SUITE}{SEP}{version}/{v.name}"))
    return jobs


def run(cfg: HeadroomConfig | None = None, executor: Executor | None = None, progress: bool = False,
        causes: Sequence[str] | None = None) -> dict:
    """Run every job (on ``executor``, default in this process) and judge each variant by the rule.

    Args:
        cfg: the headroom table's sizes (its episodes, searches and agent periods).
        executor: where the jobs run.
        progress: show a progress bar.
        causes: the causes removed (None: every cause of the suite).

    Returns:
        {"cfg", "tasks": per task {"task", "episodes", "versions": version -> the rows of
        :func:`ehss_gym.study.headroom.block_stats` (one per variant, the base law's figure 1), "verdicts": variant
        -> :func:`ehss_gym.study.factors_learned.verdict` of its overall figure}, "causes", "jobs", "computed",
        "skipped", "wall_s"}.
    """
    t0 = time.perf_counter()
    cfg = cfg or HeadroomConfig()
    executor = executor or Executor(progress=progress)
    jobs = plan(cfg, causes)
    done = list(zip(jobs, executor.map(jobs, desc=f"{PROG} --causes")))
    rows = episode_rows(done, cfg)
    ratio_rows(rows, physical_floors(cfg.eval_config().rig))
    meta = row_meta(cfg)
    tasks = []
    for task in cfg.tasks:
        per = {}
        for version in versions(causes):
            suite = f"{SUITE}{SEP}{version}"
            names = [n for n in meta if any(r["policy"] == n and r["suite"] == suite and r["task"] == task
                                            for r in rows)]
            if names:
                per[version] = block_stats(rows, suite, task, names, meta, cfg)
        if not per:
            continue
        figure = {version: {d["policy"]: d["figure"] for d in stats} for version, stats in per.items()}
        judged = [d["policy"] for d in per[AS_IS] if d["kind"] != "base"]
        verdicts = {n: verdict(figure[AS_IS][n], {v[3:]: figure[v][n] for v in per if v != AS_IS}) for n in judged}
        n_eps = len({r["episode"] for r in rows if r["suite"] == f"{SUITE}{SEP}{AS_IS}" and r["task"] == task})
        tasks.append({"task": task, "episodes": n_eps, "versions": per, "verdicts": verdicts})
    return {"cfg": cfg, "tasks": tasks, "causes": tuple(v[3:] for v in versions(causes)[1:]), "jobs": len(jobs),
            "computed": executor.computed, "skipped": executor.skipped, "wall_s": time.perf_counter() - t0}


__all__ = ["SUITE", "VARIANTS", "SEP", "versions", "version_episodes", "plan", "run"]
