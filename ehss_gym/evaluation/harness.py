"""``ehss evaluate``'s engine: scripted CLF laws (n = 2, 4, 6; n = 2 with the disturbance observer), a PID and learned
policies on the same scenarios.

Every policy acts in the Gymnasium env ``EHSSTracking-v0`` (:class:`ehss_gym.envs.env.EHSSTrackingEnv`) through
SB3's ``predict(obs, state, episode_start, deterministic=True)``; every episode is pinned to a scenario
(``reset(options={"scenario": ...})``), so all policies see exactly the same references, friction
events, plants and sensor noise. The episodes run as jobs of the execution layer (:mod:`ehss_gym.infra.execution`):
in this process, in ``spawn`` worker processes across the cores, or as Ray tasks (``--backend ray``); the split
of episodes into jobs depends neither on the number of workers nor on the backend, so results are identical
for any ``--workers`` and on both backends.
The paper suite keeps the paper's start (``bumpless=False``: the reference model at its steady state for r(0),
:data:`~ehss_gym.evaluation.suites.SUITE_ENV`); every other suite runs at the policy's own settings.

The pieces: the suites and their episodes (:mod:`~ehss_gym.evaluation.suites`), the policy specs
(:mod:`~ehss_gym.evaluation.specs`), loading a spec's runs (:mod:`~ehss_gym.evaluation.loading`), the ratios to
the reference law, the figures and the summaries (:mod:`~ehss_gym.evaluation.scoring`,
:mod:`~ehss_gym.evaluation.stats`). This module cuts the work into jobs, runs them and gathers the
:class:`Results`; the report is :mod:`ehss_gym.reporting.comparison`'s.

**Loading**: every run is loaded once, in this process, to check that it fits the env
(:func:`~ehss_gym.evaluation.specs.check_fit`); the workers get each policy once, as the jobs' shared context
(:func:`~ehss_gym.evaluation.loading.portable`: a safe-weights model as its two files' bytes), so no worker reads
a model file (a model that cannot be pickled is loaded at most once per worker).
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from ehss_gym.controllers import dob_rows
from ehss_gym.core.response import step_metrics
from ehss_gym.core.rig import as_rig
from ehss_gym.envs.rollouts import SideBySide
from ehss_gym.envs.rollouts import rollout as run_rollout
from ehss_gym.infra.execution import Backend, Executor, Job, canonical, pin_blas, usable_cores

from .loading import PolicyError, load_run, portable, restore
from .scoring import METRIC_KEYS, METRICS, STEP_KEYS, physical_floors, ratio_rows, summarize
from .specs import (
    REFERENCE_POLICY,
    SCRIPTED_DEFAULT,
    PolicySpec,
    check_fit,
    check_unique_names,
    default_specs,
    learned_spec,
    object_spec,
    parse_policy,
    scripted_spec,
    scripted_specs,
    shipped_specs,
)
from .suites import SUITE_ENV, SUITES, SWEEP_WINDOW, TASKS, UNITS, Episode, EvalConfig, build_episodes, step_of

# beyond METRICS
ROW_EXTRAS = ("su_iae", "peak_u", "tv_u", "divergence_reason", "t_diverged", "t_lost_track", "n_clipped", "t_tracking",
              "t_disturbance")
TRACED_SUITES = ("paper", "step")  # suites whose episodes are traced at the agent rate (figures, step metrics)


@dataclass
class EpisodeBatch:
    """One policy run on a list of episodes of one suite and task (an executor job runs one, or several that differ
    only in their run: :func:`make_jobs`).

    Attributes:
        job_id: index in the job list.
        policy: the spec's name.
        run_index: which run (training seed) of the spec.
        task: the task of its episodes.
        env_kwargs: the env settings the policy acts in on that task.
        episodes: the episodes (all of one suite).
        trace: record the agent-rate traces (the paper suite's, kept for the figures; the step suite's, for its
            step-response metrics).
    """

    job_id: int
    policy: str
    run_index: int
    task: str
    env_kwargs: dict
    episodes: list
    trace: bool = False

    @property
    def key(self) -> tuple:
        """(policy, run, task): which loaded policy the job runs."""
        return self.policy, self.run_index, self.task

    @property
    def cost(self) -> float:
        """Simulated seconds of the job [s] (its episodes' durations)."""
        return sum(ep.t_end for ep in self.episodes)


@dataclass
class Results:
    """Everything an evaluation produced."""

    cfg: EvalConfig
    specs: list
    episodes: list
    rows: list  # per-episode records (dicts)
    traces: dict  # (policy, run, task) -> paper trace
    summary: list  # per (suite, task, policy) dicts
    comparisons: list  # learned vs best CLF / base law
    wall_time: float = math.nan  # [s] from ``started`` to the end of the last phase timed
    # phase -> wall time [s]: setup, episodes, statistics (here), then start-up (the command line's imports before
    # the evaluation), bounds, figures and report (added by the command and the report)
    timings: dict = field(default_factory=dict)
    started: float = math.nan  # time.perf_counter() when the work began (the evaluation, or the command before it)
    workers: int = 1
    command: str = "ehss evaluate"
    notes: list = field(default_factory=list)


_MADE: dict = {}  # this process's policy objects, by (digest of their item, (policy, run, task))


def item_digest(item: tuple) -> str:
    """SHA-256 of a policy item (:func:`ehss_gym.evaluation.loading.portable`): part of its jobs' addresses."""
    how, what = item
    return hashlib.sha256(json.dumps([how, canonical(what)]).encode()).hexdigest()


def _eval_job(config: dict, seed: int, items: dict) -> list[dict]:
    """An executor job (:mod:`ehss_gym.infra.execution`): :class:`EpisodeBatch` es that differ only in their run
    (:func:`make_jobs`), side by side in one rollout, each run's policy made once per process from its item in
    ``items``; plain data back per batch (per-episode metrics, traces or None)."""
    batches: list[EpisodeBatch] = config["batches"]
    parts = []
    for batch, digest in zip(batches, config["items"]):
        # one object per item *and* (policy, run, task) and env settings: a scripted law's item is the same for both
        # tasks and every suite, its object is built for one task and loop
        made = (digest, batch.key, json.dumps(canonical(batch.env_kwargs)))
        if made not in _MADE:
            _MADE[made] = restore(items[batch.key], batch.task, batch.env_kwargs)
        parts.append((_MADE[made], len(batch.episodes)))
    first = batches[0]
    policy = parts[0][0] if len(parts) == 1 else SideBySide(parts)
    res, traces = rollout(policy, first.env_kwargs, [ep for b in batches for ep in b.episodes], first.trace,
                          first.policy)
    out, s = [], 0
    for batch in batches:
        n = len(batch.episodes)
        tr = None if traces is None else traces[s:s + n]
        if tr is not None:
            for ep, m, trace in zip(batch.episodes, res[s:s + n], tr):
                if ep.suite == "step":
                    m.update(step_response(trace, ep))
            if batch.episodes[0].suite != "paper":
                tr = None
        out.append({"metrics": res[s:s + n], "traces": tr})
        s += n
    return out


def step_response(trace: dict, ep: Episode) -> dict:
    """The step-response metrics of a step-suite episode from its agent-rate trace of the true output
    (:func:`ehss_gym.core.response.step_metrics`: the response r -> y, from rest at 0 to the step's amplitude):
    ``step_rise_time`` [s] (10-90 %), ``step_overshoot`` [%], ``step_settling_time`` [s] (2 % band)."""
    t_step, amplitude = step_of(ep)
    m = step_metrics(trace["t"], trace["y"], t_step, 0.0, amplitude)
    return {f"step_{k}": m[k] for k in ("rise_time", "overshoot", "settling_time")}


def rollout(policy, env_kwargs: dict, episodes: Sequence[Episode], trace: bool = False, name: str = "policy"):
    """Run ``policy`` on pinned episodes side by side: :func:`ehss_gym.envs.rollouts.rollout`, the one loop.

    Args:
        policy: an object with SB3's ``predict``.
        env_kwargs: the env settings it acts in.
        episodes: the episodes (their physical fields are pinned, one lane each).
        trace: record the traces.
        name: the policy's name in error messages.

    Returns:
        (list of per-episode dicts: the core metrics plus ``n_clipped`` and ``agent_steps``,
        list of trace dicts or None). A trace holds, per agent step, t [s], y_ref and y [output unit],
        e [output unit], u [mA] (applied) and friction [N*m].
    """
    # the rows keep no return: the env skips the base law's run of each episode that the reward's constants need
    res = run_rollout(policy, env_kwargs, [ep.physical for ep in episodes], trace=trace, name=name, returns=False)
    return [r.metrics for r in res], ([r.trace for r in res] if trace else None)


def make_batches(specs: Sequence[PolicySpec], episodes: Sequence[Episode], chunk: int) -> list[EpisodeBatch]:
    """Split the work into batches: (policy, run, task, suite) groups cut into at most ``chunk`` episodes."""
    batches: list[EpisodeBatch] = []
    for spec in specs:
        for r in range(len(spec.runs)):
            for task in TASKS:
                if task not in spec.tasks:
                    continue
                for suite in SUITES:
                    eps = [ep for ep in episodes if ep.task == task and ep.suite == suite]
                    if not eps:
                        continue
                    n_parts = -(-len(eps) // chunk)
                    kw = {**spec.env_kwargs_for(task), **SUITE_ENV.get(suite, {})}
                    for part in np.array_split(np.arange(len(eps)), n_parts):
                        batches.append(EpisodeBatch(len(batches), spec.name, r, task, kw, [eps[i] for i in part],
                                                    trace=suite in TRACED_SUITES))
    return batches


def default_workers() -> int:
    """The cores this process may run on."""
    return usable_cores()


def make_jobs(batches: Sequence[EpisodeBatch]) -> list[list[EpisodeBatch]]:
    """The batches grouped into jobs: those that differ only in their run (a learned policy's training seeds on the
    same episodes and env settings) run side by side in one vector env, each run's policy predicting for its own
    lanes (:class:`~ehss_gym.envs.rollouts.SideBySide`), so one agent step of Python serves every run. A run's
    policy still gets the batch of observations it would get alone, so its float32 forward pass rounds the same."""
    groups: dict = {}
    for b in batches:
        key = (b.policy, b.task, b.trace, json.dumps(canonical(b.env_kwargs)),
               tuple((ep.suite, ep.episode_id) for ep in b.episodes))
        groups.setdefault(key, []).append(b)
    return list(groups.values())


def run_batches(batches: Sequence[EpisodeBatch], items: dict, executor: Executor, in_process: bool = False) -> dict:
    """Run the batches as jobs (:func:`make_jobs`) on ``executor``'s backend (:mod:`ehss_gym.infra.execution`),
    longest first.

    Args:
        batches: the batches.
        items: (policy, run, task) -> how to make the policy (:func:`ehss_gym.evaluation.loading.portable`, or
            ("object", policy) in this process).
        executor: where they run (its store, if any, keeps each job's result under its content address).
        in_process: run them in this process whatever the backend (policies that cannot travel).

    Returns:
        job_id -> (per-episode metrics, traces or None), per batch.
    """
    groups = sorted(make_jobs(batches), key=lambda g: -sum(b.cost for b in g))  # longest first: busy to the end
    digests = {k: item_digest(item) if item[0] != "object" else f"object-{id(item[1])}" for k, item in items.items()}
    jobs = [Job(_eval_job, {"batches": g, "items": [digests[b.key] for b in g]}, seed=0,
                label=f"{g[0].policy}/{g[0].task}#{g[0].job_id}") for g in groups]
    store = executor.store
    if any(item[0] == "object" for item in items.values()):  # a Python object has no content address
        executor.store = None
    try:
        results = executor.map(jobs, context=items, desc="ehss evaluate", in_process=True if in_process else None)
    finally:
        executor.store = store
    return {b.job_id: (r["metrics"], r["traces"]) for g, rs in zip(groups, results) for b, r in zip(g, rs)}


def _complete_specs(specs: list, cfg: EvalConfig, notes: list) -> list:
    """The specs with the reference law added, the scripted ones on the evaluation's plant."""
    check_unique_names(specs)
    names = [s.name for s in specs]
    if REFERENCE_POLICY not in names:
        specs.insert(0, scripted_spec(REFERENCE_POLICY))
        notes.append(f"{REFERENCE_POLICY} was added: every ratio is taken to it.")
    return [on_plant(s, cfg, notes) for s in specs]


def on_plant(spec: PolicySpec, cfg: EvalConfig, notes: list) -> PolicySpec:
    """A scripted law acts on the evaluation's plant (its current limit the rig's rated current, the PID tuned on it)
    with the evaluation's law settings (the CLF law's row of its n, the observer's and the PID's rows per task); a
    learned policy keeps the settings it was trained with (a note says when its plant is not the evaluated one)."""
    env = cfg.env_kwargs()
    if not env:
        return spec
    if spec.kind in ("clf", "pid"):
        return _tuned_rows(replace(spec, env_kwargs={**spec.env_kwargs, **env}), cfg.law_settings)
    trained = spec.env_kwargs.get("plant")
    if cfg.plant is None:
        return spec
    if trained is None or as_rig(trained) != cfg.rig:
        notes.append(f"{spec.name} acts with the settings it was trained with, on plant "
                     f"{'Table I' if trained is None else as_rig(trained).label}; the episodes are {cfg.rig.label}'s.")
    return spec


def _tuned_rows(spec: PolicySpec, table) -> PolicySpec:
    """A scripted spec with a law table's per-task rows: ``dob-n2``'s observer bandwidth, smoothing and layer, the
    compensators' sizes (and so the tasks they act on), the PID's gains (unless the spec gives its own); the CLF law's
    rows come with the table itself (env ``law_settings``).
    """
    if table is None:
        return spec
    if spec.kind == "clf" and spec.runs[0].get("scripted"):  # a compensator: the table's rows, tasks and words
        return replace(scripted_spec(spec.runs[0]["scripted"], spec.name, laws=table), env_kwargs=spec.env_kwargs)
    if spec.kind == "clf" and spec.env_kwargs.get("dob_hz") and spec.env_kwargs.get("n") == 2:
        rows = dob_rows(spec.tasks, table)
        return replace(spec, task_kwargs=rows, source=spec.source + f"; observer rows of {table.describe()}")
    if spec.kind == "pid" and not spec.runs[0].get("gains"):
        gains = {t: table.tasks[t].pid for t in spec.tasks if t in table.tasks and table.tasks[t].pid}
        return replace(spec, runs=[{**spec.runs[0], "gains": gains}], source=spec.source + f"; gains of "
                                                                                          f"{table.describe()}")
    return replace(spec, source=spec.source + f"; {table.describe()}")


def _check_tasks(specs: list, cfg: EvalConfig, named: set, notes: list) -> None:
    """PolicyError for a policy the caller named that acts on none of the evaluated tasks (it would vanish from
    the report); a note for such a default policy (a shipped model of the task left out)."""
    for spec in specs:
        if any(t in cfg.tasks for t in spec.tasks):
            continue
        if spec.name in named and not spec.tasks:
            raise PolicyError(f"policy {spec.name!r} acts on no task: {spec.source}; a law table without its rows "
                              "is of an earlier release (rerun ehss baselines)")
        if spec.name in named:
            raise PolicyError(f"policy {spec.name!r} acts on task(s) {', '.join(spec.tasks)} only, and the evaluated "
                              f"tasks are {', '.join(cfg.tasks)} (--tasks): it would not be evaluated; add its task "
                              "or leave it out")
        notes.append(f"{spec.name} acts on no task ({spec.source}); skipped." if not spec.tasks else
                     f"{spec.name} acts on task {spec.tasks[0]!r} only, which is not evaluated; skipped.")


def _load_runs(specs: list, cfg: EvalConfig, notes: list) -> dict:
    """Load every run on every evaluated task once and check that it fits the env; (policy, run, task) -> object.

    A PID's tuned gains are stored in its run, so it is not tuned again where its episodes run.
    """
    loaded = {}
    for spec in specs:
        run_tasks = [t for t in spec.tasks if t in cfg.tasks]
        for task in run_tasks:
            for r, run in enumerate(spec.runs):
                try:
                    pol = load_run(run, task, spec.env_kwargs_for(task))
                except ValueError as exc:  # PolicyError, SafeWeightsError, bad env settings
                    msg = str(exc)
                    raise PolicyError(msg if msg.startswith("policy ") else f"policy {spec.name!r}: {msg}") from None
                check_fit(spec, pol, task)
                if spec.kind == "pid":  # tuned once here, not again in every worker
                    run.setdefault("gains", {})[task] = (pol.kp, pol.ki, pol.kd)
                loaded[(spec.name, r, task)] = pol
    return loaded


def _policy_items(specs: list, loaded: dict, workers: int, notes: list) -> tuple[dict, int]:
    """How each process gets each policy: (items for :func:`run_batches`, workers; 1 = in this process).

    Scripted laws are built afresh from their description where their episodes run; loaded models are handed
    over (in this process) or sent as bytes (to workers). An object that does not pickle keeps the episodes in
    this process.
    """
    runs = {(s.name, r): run for s in specs for r, run in enumerate(s.runs)}
    if workers > 1:
        try:
            return {k: portable(runs[k[:2]], pol) for k, pol in loaded.items()}, workers
        except Exception:  # unpicklable user objects cannot travel to worker processes
            notes.append("a Python policy object could not be pickled; episodes ran in one process.")
    items = {k: ("build", runs[k[:2]]) if isinstance(runs[k[:2]], dict) else ("object", pol)
             for k, pol in loaded.items()}
    return items, 1


def _gather(batches: Sequence[EpisodeBatch], done: dict) -> tuple[list, dict]:
    """Per-episode rows (labels, metrics) and the paper traces of finished batches, in batch order."""
    rows, traces = [], {}
    for batch in batches:
        res, tr = done[batch.job_id]
        for ep, m in zip(batch.episodes, res):
            row = {"suite": ep.suite, "task": ep.task, "policy": batch.policy, "run": batch.run_index,
                   "episode": ep.episode_id, "sweep": ep.sweep, "level": ep.level, "scenario_seed": ep.scenario_seed,
                   "t_end": ep.t_end}
            row["noisy"] = any(v > 0.0 for v in ep.physical["noise_std"])
            row.update({k: m[k] for k in METRIC_KEYS})
            row.update({k: m[k] for k in ROW_EXTRAS})
            row.update({k: m.get(k, math.nan) for k in STEP_KEYS})
            rows.append(row)
        if tr is not None:
            for ep, trace in zip(batch.episodes, tr):
                traces[(batch.policy, batch.run_index, ep.task)] = trace
    return rows, traces


def _checked_episodes(episodes: Sequence[Episode], cfg: EvalConfig) -> list[Episode]:
    """Episodes given to :func:`evaluate`; ValueError for one outside ``cfg``'s suites and tasks or a repeated id."""
    out = list(episodes)
    keys = [(ep.suite, ep.task, ep.episode_id) for ep in out]
    bad = [k for k in keys if k[0] not in cfg.suites or k[1] not in cfg.tasks]
    if bad or not out:
        raise ValueError(f"episodes must be a non-empty list of episodes of the suites {list(cfg.suites)} and tasks "
                         f"{list(cfg.tasks)}, got {bad[0] if bad else 'none'}")
    if len(set(keys)) != len(keys):
        raise ValueError("episodes: each (suite, task, episode_id) must be unique")
    return out


def evaluate(specs: Sequence[PolicySpec] | None = None, cfg: EvalConfig | None = None, workers: int | None = None,
             progress: bool = True, command: str = "ehss evaluate", executor: Executor | None = None,
             episodes: Sequence[Episode] | None = None) -> Results:
    """Evaluate policies on the configured suites (see the module docstring).

    Args:
        specs: policies (default: :func:`~ehss_gym.evaluation.specs.default_specs`). The reference law
            :data:`~ehss_gym.evaluation.specs.REFERENCE_POLICY` is added when missing (every ratio is taken to it).
        cfg: sizes and seeds (default :class:`~ehss_gym.evaluation.suites.EvalConfig`).
        workers: processes (default: the cores available); 1 runs in this process.
        progress: show a tqdm progress bar on stderr.
        command: the command line recorded in the report.
        executor: where the episodes run (:mod:`ehss_gym.infra.execution`; its backend, and its store if it has
            one); default: this machine's processes, ``workers`` of them, nothing stored.
        episodes: the episodes (default: :func:`~ehss_gym.evaluation.suites.build_episodes` of ``cfg``); given, they
            replace the suites' (e.g. the same episodes with one cause removed, ``ehss factors --learned``), each
            id unique within its suite and task, every one a suite and task of ``cfg``.

    Raises:
        PolicyError: a policy that cannot be loaded, whose shapes do not fit the env, or (among ``specs``) that acts
            on none of ``cfg.tasks``.
    """
    t_start = time.perf_counter()
    pin_blas()  # before the first forward pass of a learned policy (the shape checks below)
    cfg = cfg or EvalConfig()
    notes: list = []
    named = set() if specs is None else {s.name for s in specs}
    specs = _complete_specs(list(default_specs() if specs is None else specs), cfg, notes)
    _check_tasks(specs, cfg, named, notes)
    loaded = _load_runs(specs, cfg, notes)
    specs = [replace(s, tasks=tuple(t for t in s.tasks if t in cfg.tasks)) for s in specs]
    specs = [s for s in specs if s.tasks]
    episodes = build_episodes(cfg) if episodes is None else _checked_episodes(episodes, cfg)
    batches = make_batches(specs, episodes, cfg.chunk)
    executor = executor or Executor(Backend("local", workers=workers), progress=progress)
    remote = executor.backend.name != "local"
    workers = max(1, min(executor.workers(), len(batches)))
    # off this process (worker processes, Ray), a policy travels as its item; in it, as the object itself
    items, travel = _policy_items(specs, loaded, max(2, workers) if remote else workers, notes)
    workers = workers if travel > 1 else 1
    t0 = time.perf_counter()
    done = run_batches(batches, items, executor, in_process=travel == 1)
    rows, traces = _gather(batches, done)
    t1 = time.perf_counter()
    ratio_rows(rows, physical_floors(cfg.rig))
    summary, comparisons = summarize(rows, specs, cfg)
    t2 = time.perf_counter()
    timings = {"setup": t0 - t_start, "episodes": t1 - t0, "statistics": t2 - t1}
    return Results(cfg=cfg, specs=specs, episodes=episodes, rows=rows, traces=traces, summary=summary,
                   comparisons=comparisons, wall_time=t2 - t_start, timings=timings, workers=workers,
                   command=command, notes=notes, started=t_start)


# the names callers use as ``harness.<name>`` (the training report and validation: ``from ehss_gym.evaluation
# import harness as ev``); each is defined in the module named in the package docstring
__all__ = ["EvalConfig", "PolicySpec", "PolicyError", "Episode", "EpisodeBatch", "Results", "evaluate", "parse_policy",
           "scripted_spec", "scripted_specs", "learned_spec", "object_spec", "shipped_specs", "default_specs",
           "build_episodes", "rollout", "check_fit", "make_batches", "make_jobs", "run_batches", "default_workers",
           "REFERENCE_POLICY", "SCRIPTED_DEFAULT", "METRICS", "METRIC_KEYS", "TASKS", "SUITES", "UNITS",
           "SWEEP_WINDOW"]
