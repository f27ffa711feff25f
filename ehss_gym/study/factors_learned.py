"""Where the learned policies' figures come from (``ehss factors --learned``): each cause removed, each window split.

The policies: the scripted laws :data:`SCRIPTED` (the reference clf-n2 among them) and the shipped learned groups
of each task at n = 2 (:data:`LEARNED_FAMILIES`: ``residual-ppo-<task>-n2``, ``residual-sac-<task>-n2``, whichever
are in ``ehss_gym/models``; every training seed of a group), on the held-out and the unmodelled suite of
``ehss evaluate``, run through its harness (:func:`ehss_gym.evaluation.harness.evaluate`, the one rollout loop) on the
suites' episodes as they are and with one cause removed at a time (:data:`ehss_gym.study.factors.CAUSES`, the same
functions as the scripted factor table): **friction** (every event's amplitude 0, its window kept), **mismatch**
(the true plant set to the controller's model), **noise** (the sensor noise removed), and on the unmodelled suite
also each group of its effects: **valve** (threshold and hysteresis), **delay** (the sensor delay),
**quantisation** (encoder and velocity). Every policy, clf-n2 included, runs every variant, so each figure is still
a ratio on identical episodes.

Per (suite, task, variant) and policy: the overall figure G (the ruler's, :class:`ehss_gym.evaluation.scoring.Block`)
and its split: the tracking window (t >= 0.2 s outside the friction windows and their 0.2 s guard), the
disturbance windows (friction events + 0.2 s guard), the effort or chatter class (the current), each as the
geometric mean over episodes and seeds of the episode's ratio to clf-n2; and the start-up window (t < 0.2 s, the
pair su_rmse, su_iae floored as the ruler floors an error), which is in no class: a diagnostic of what G leaves
out. Removing the noise moves an episode from the chatter class to the effort class (for every policy alike).

**The rule** (:func:`verdict`, written before the runs): a learned group's G on a suite is *level* with clf-n2 if
it lies within :data:`NEAR` (2 %) of 1; otherwise its advantage (G < 1) or loss (G > 1) is *explained by* a cause
if removing that cause takes G within 2 % of 1 or across 1, and *mostly* due to a cause if removing it takes away
at least half of log G (:data:`MOSTLY`); a cause whose removal widens the gap by more than 2 % on the same side of
1 *works for* the gap (the gap is larger without it). Which window carries the gap: each class's share of log G (G
is the geometric mean of its class figures, so log G is the mean of their logs).
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from ehss_gym.evaluation.harness import evaluate
from ehss_gym.evaluation.scoring import (
    STARTUP_METRICS,
    Block,
    pair_log_ratio,
    physical_floors,
)
from ehss_gym.evaluation.specs import REFERENCE_POLICY, PolicySpec, scripted_specs, shipped_specs
from ehss_gym.evaluation.suites import TASKS, Episode, EvalConfig, build_episodes
from ehss_gym.infra.execution import Executor

from .factors import CAUSES, PROG, removed

SUITES = ("heldout", "unmodelled")
SCRIPTED = ("clf-n2", "dob-n2", "dcomp-n2", "vinv-n2", "eso-n2")
LEARNED_FAMILIES = ("residual-ppo", "residual-sac")
SUITE_CAUSES = {"heldout": ("friction", "mismatch", "noise"),
                "unmodelled": ("friction", "mismatch", "noise", "valve", "delay", "quantisation")}
AS_IS = "as is"
NEAR = 0.02  # [-] the rule: a G within 2 % of 1 is level with clf-n2
MOSTLY = 0.5  # [-] the rule: a removal that takes away at least half of log G
WINDOWS = ("startup", "tracking", "disturbance", "current")  # the split; "current": the effort or chatter class
SEP = "|"  # an episode's id in a variant: "<suite's id>|<variant>"


def variant_names(suite: str) -> tuple[str, ...]:
    """The variants of a suite: as is, then each cause removed ("no <cause>")."""
    return (AS_IS,) + tuple(f"no {c}" for c in SUITE_CAUSES[suite])


def variant_episodes(episodes: Sequence[Episode]) -> list[Episode]:
    """Every episode in every variant of its suite, its id tagged with the variant (``heldout-3|no friction``)."""
    out = []
    for ep in episodes:
        for v in variant_names(ep.suite):
            fns = () if v == AS_IS else (CAUSES[v[3:]],)
            out.append(replace(ep, episode_id=f"{ep.episode_id}{SEP}{v}", physical=removed(ep.physical, fns)))
    return out


def variant_of(episode_id: str) -> str:
    """The variant of a tagged episode id."""
    return episode_id.rsplit(SEP, 1)[1]


def learned_specs(tasks: Sequence[str], families: Sequence[str] = LEARNED_FAMILIES) -> list[PolicySpec]:
    """The shipped learned groups ``<family>-<task>-n2`` of the tasks (those in ``ehss_gym/models``)."""
    want = re.compile(rf"^({'|'.join(map(re.escape, families))})-({'|'.join(tasks)})-n2$")
    return [s for s in shipped_specs() if want.match(s.name)]


def _startup_logs(rows: list, name: str, kept: Sequence[str], task: str, floors) -> np.ndarray:
    """The start-up window's log ratios of a policy's runs on the episodes ``kept`` (NaN where undefined)."""
    ref = {r["episode"]: r for r in rows if r["policy"] == REFERENCE_POLICY}
    keep = set(kept)
    return np.array([pair_log_ratio(r, ref[r["episode"]], STARTUP_METRICS, task, floors)
                     for r in rows if r["policy"] == name and r["episode"] in keep])


def _gmean(logs) -> float:
    """exp of the mean of the finite logs (NaN if none)."""
    v = np.asarray(logs, dtype=np.float64)
    v = v[np.isfinite(v)]
    return math.exp(float(v.mean())) if v.size else math.nan


def block_figures(rows: list, names: Sequence[str], suite: str, task: str, floors) -> dict:
    """Per policy on one (suite, task, variant)'s rows: G, each window's ratio (:data:`WINDOWS`), each class's
    share of log G, and the episodes used."""
    blk = Block(rows, names, suite, task)
    out = {}
    for n in names:
        g, gc = blk.figure(n)
        cur = [c for c in ("effort", "chatter") if c in gc]
        cur_logs = np.concatenate([blk.logs[n][c].ravel() for c in cur]) if cur else []
        win = {"startup": _gmean(_startup_logs(rows, n, blk.kept[n], task, floors)),
               "tracking": gc.get("tracking", math.nan), "disturbance": gc.get("disturbance", math.nan),
               "current": _gmean(cur_logs)}
        share = {c: math.log(v) / len(gc) / math.log(g) if g > 0 and g != 1.0 else math.nan for c, v in gc.items()}
        out[n] = {"G": g, "classes": gc, "windows": win, "share": share, "used": len(blk.kept[n])}
    return out


def verdict(g: float, removed_g: dict) -> dict:
    """The rule (module docstring) for one learned group on one suite.

    Args:
        g: its G as is.
        removed_g: cause -> its G with that cause removed.

    Returns:
        {"gap": "advantage", "loss" or "level"; "explained": causes whose removal takes G within NEAR of 1 or across
        it; "mostly": causes whose removal takes away at least MOSTLY of log G (the explained ones included);
        "widens": causes whose removal widens the gap by more than NEAR, G on the same side of 1;
        "removed_share": cause -> the share of log G its removal takes away (1 = all of it, > 1 across 1, < 0 the gap
        widened)}.
    """
    near = math.log1p(NEAR)
    lg = math.log(g) if g > 0 else math.nan
    if not math.isfinite(lg):
        return {"gap": "undefined", "explained": [], "mostly": [], "widens": [], "removed_share": {}}
    if abs(lg) <= near:
        return {"gap": "level", "explained": [], "mostly": [], "widens": [], "removed_share": {}}
    share, explained, mostly, widens = {}, [], [], []
    for cause, gr in removed_g.items():
        lr = math.log(gr) if gr > 0 else math.nan
        if not math.isfinite(lr):
            continue
        share[cause] = 1.0 - lr / lg
        if abs(lr) <= near or lr * lg < 0:
            explained.append(cause)
        if share[cause] >= MOSTLY:
            mostly.append(cause)
        if lr * lg > 0 and abs(lr) - abs(lg) > near:  # the same side of 1, further from it
            widens.append(cause)
    return {"gap": "advantage" if lg < 0 else "loss", "explained": explained, "mostly": mostly, "widens": widens,
            "removed_share": share}


def _suite_task(rows: list, names: Sequence[str], suite: str, task: str, floors, learned: Sequence[str]) -> dict:
    """One (suite, task): per variant the figures of every policy, and the rule's verdict per learned group."""
    sel = [r for r in rows if r["suite"] == suite and r["task"] == task]
    figs = {v: block_figures([r for r in sel if variant_of(r["episode"]) == v], names, suite, task, floors)
            for v in variant_names(suite)}
    verdicts = {n: verdict(figs[AS_IS][n]["G"], {v[3:]: figs[v][n]["G"] for v in variant_names(suite)[1:]})
                for n in learned}
    return {"suite": suite, "task": task, "variants": figs, "verdicts": verdicts,
            "episodes": len({r["episode"] for r in sel if r["policy"] == REFERENCE_POLICY}) // len(figs)}


def run(tasks: Sequence[str] = TASKS, episodes: int = 16, executor: Executor | None = None, progress: bool = False,
        specs: Sequence[PolicySpec] | None = None, episode_seconds: float = 2.0) -> dict:
    """The scripted laws and the learned groups on both suites, as they are and with each cause removed.

    Args:
        tasks: the tasks.
        episodes: episodes per suite and task (the first of ``ehss evaluate``'s held-out and unmodelled suites).
        executor: where the episodes run (default: this machine's cores).
        progress: show a progress bar.
        specs: the policies (default: :data:`SCRIPTED` and :func:`learned_specs` of the tasks); clf-n2 is added.
        episode_seconds: duration of an episode [s].

    Returns:
        {"blocks": one :func:`_suite_task` dict per (suite, task), "policies": names, "learned": the learned
        groups' names, "runs": name -> training seeds, "episodes", "rows": the harness's per-episode rows (each
        episode id tagged with its variant, :func:`variant_of`), "wall_s"}.
    """
    t0 = time.perf_counter()
    specs = list(specs) if specs is not None else (scripted_specs(SCRIPTED, tasks) + learned_specs(tasks))
    cfg = EvalConfig(suites=SUITES, tasks=tuple(tasks), heldout_episodes=episodes, episode_seconds=episode_seconds,
                     n_boot=100)
    eps = variant_episodes(build_episodes(cfg))
    res = evaluate(specs, cfg, progress=progress, command=PROG + " --learned", executor=executor, episodes=eps)
    names = [s.name for s in res.specs]
    floors = physical_floors(cfg.rig)
    blocks = []
    for suite in SUITES:
        for task in tasks:
            here = [s.name for s in res.specs if task in s.tasks]
            learned = [s.name for s in res.specs if s.learned and task in s.tasks]
            blocks.append(_suite_task(res.rows, here, suite, task, floors, learned))
    return {"blocks": blocks, "policies": names, "learned": [s.name for s in res.specs if s.learned],
            "runs": {s.name: len(s.runs) for s in res.specs}, "episodes": episodes, "rows": res.rows,
            "wall_s": time.perf_counter() - t0}


__all__ = ["SUITES", "SCRIPTED", "LEARNED_FAMILIES", "SUITE_CAUSES", "NEAR", "MOSTLY", "WINDOWS", "variant_names",
           "variant_episodes", "variant_of", "learned_specs", "block_figures", "verdict", "run"]
