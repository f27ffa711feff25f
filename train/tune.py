"""``ehss tune``: hyperparameter search for the residual agent with Ray Tune, Optuna's TPE sampler and ASHA.

Each trial trains residual PPO (:func:`ehss_gym.train.loop.train`) with hyperparameters drawn from
:data:`SEARCH_SPACE` and reports every held-out validation evaluation (the validation block of scenario seeds,
disjoint from training and from the harness's test block) to Tune: ``figure`` and ``failed`` (the policy now;
:mod:`ehss_gym.evaluation.heldout`) and ``best_objective`` (the best so far, the policy a run keeps, as one number:
its overall figure if it passed the failure gate, inf if it failed). The search minimises ``best_objective``; ASHA
stops the
trials that trail at its rungs (measured in agent steps). A trial trains into ``<out>/trials/<run name>`` with
checkpoints, so a search restarted after an interruption (the same command) resumes from Tune's experiment
state in ``<out>/search`` and each unfinished trial from its last checkpoint.

This module imports Ray and Optuna (the ``ray`` extra); the CLI imports it only when ``ehss tune`` runs.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from dataclasses import dataclass

import optuna
from ray import tune
from ray.tune.schedulers import ASHAScheduler
from ray.tune.search import ConcurrencyLimiter
from ray.tune.search.optuna import OptunaSearch

from ehss_gym.agents.specs import get_spec
from ehss_gym.infra.execution import Executor
from ehss_gym.infra.util import atomic_write_text

from . import runs
from .config import Config
from .jobs import materialize, seed_job
from .loop import train

AGENT = "residual-ppo"
METRIC = "best_objective"  # the best validation so far as one number (lower is better; heldout.tune_objective)
# (kind, low, high) or ("choice", values): the residual agent's hyperparameters (ehss_gym.agents.specs.AgentSpec)
SEARCH_SPACE = {
    "learning_rate": ("loguniform", 3e-5, 1e-3),
    "gamma": ("uniform", 0.9, 0.995),
    "gae_lambda": ("uniform", 0.8, 0.99),
    "clip_range": ("uniform", 0.1, 0.3),
    "n_epochs": ("choice", [3, 5, 10]),
    "log_std_init": ("uniform", -3.0, -1.0),
}


@dataclass
class TuneSettings:
    """The search's settings (``ehss tune``'s options).

    Attributes:
        task, n: the residual agent's task and base-law power factor.
        trials: configurations tried.
        timesteps: agent steps of a trial that ASHA does not stop (also the best config's budget).
        eval_freq: agent steps between validation evaluations (ASHA's rungs fall on them).
        grace: agent steps before ASHA may stop a trial.
        eval_episodes, eval_seconds: validation scenarios per evaluation and their duration [s].
        n_envs: parallel envs per trial (None: the agent's default).
        seed: the trials' training seed and the TPE sampler's seed.
        concurrent: trials at a time (each takes one CPU).
        compare_seeds: fresh seeds that train the best config and the shipped recipe for the comparison (0: none).
        fixed_hp: hyperparameter overrides every trial (and the best config) keeps, not searched.
        out: the search's folder.
    """

    task: str = "velocity"
    n: int = 2
    trials: int = 16
    timesteps: int = 100_000
    eval_freq: int = 25_000
    grace: int = 25_000
    eval_episodes: int = 8
    eval_seconds: float = 2.0
    n_envs: int | None = None
    seed: int = 0
    concurrent: int = 2
    compare_seeds: int = 0
    fixed_hp: dict = dataclasses.field(default_factory=dict)
    out: str = os.path.join("runs", "tune")

    def base_config(self, hp: dict, seed: int, parent: str) -> Config:
        """The training Config of a trial (or comparison run) with overrides ``hp`` and ``seed``, its run folder
        under ``parent``."""
        cfg = Config(agent=AGENT, task=self.task, n=self.n, timesteps=self.timesteps, seed=seed,
                     eval_freq=self.eval_freq, eval_episodes=self.eval_episodes, eval_seconds=self.eval_seconds,
                     checkpoint_freq=self.eval_freq, n_envs=self.n_envs, hp={**self.fixed_hp, **hp},
                     progress=False)
        cfg.validate()
        return dataclasses.replace(cfg, out=os.path.join(os.path.abspath(parent), cfg.run_name()))


def tune_space() -> dict:
    """:data:`SEARCH_SPACE` as Ray Tune distributions."""
    out = {}
    for name, (kind, *args) in SEARCH_SPACE.items():
        out[name] = tune.choice(args[0]) if kind == "choice" else getattr(tune, kind)(*args)
    return out


def trainable(params: dict, settings: TuneSettings) -> None:
    """One trial: train with ``params``, reporting every validation evaluation; resumes its own checkpoint."""
    cfg = settings.base_config(params, settings.seed, os.path.join(settings.out, "trials"))
    cfg = dataclasses.replace(cfg, resume=runs.latest_checkpoint(cfg.out) is not None)

    def report(row: dict) -> None:
        tune.report({"figure": row["figure"], "failed": row["failed"], METRIC: row["best_objective"],
                     "step": row["step"], "rel_tracking": row["rel_tracking"], "rel_effort": row["rel_effort"],
                     "run": cfg.run_name()})

    train(cfg, on_eval=report)


def make_tuner(settings: TuneSettings) -> tune.Tuner:
    """A new Tuner, or the interrupted search in ``<out>/search`` restored (the same settings go on)."""
    storage = os.path.abspath(settings.out)
    fn = tune.with_resources(tune.with_parameters(trainable, settings=settings), {"cpu": 1})
    path = os.path.join(storage, "search")
    if tune.Tuner.can_restore(path):
        return tune.Tuner.restore(path, trainable=fn, resume_unfinished=True, resume_errored=True)
    sampler = optuna.samplers.TPESampler(seed=settings.seed)
    search = ConcurrencyLimiter(OptunaSearch(metric=METRIC, mode="min", sampler=sampler),
                                max_concurrent=settings.concurrent)
    asha = ASHAScheduler(time_attr="step", max_t=settings.timesteps, grace_period=settings.grace,
                         reduction_factor=3)
    return tune.Tuner(fn, param_space=tune_space(),
                      tune_config=tune.TuneConfig(search_alg=search, scheduler=asha, num_samples=settings.trials,
                                                  metric=METRIC, mode="min"),
                      run_config=tune.RunConfig(name="search", storage_path=storage, verbose=0))


def trial_rows(results) -> list[dict]:
    """One row per trial (its hyperparameters, steps trained, best objective and last validation figure), best
    first."""
    rows = []
    for r in results:
        m = r.metrics or {}
        # Tune's folder name is trainable_<id>_<number>_<the params>: the params are columns of their own
        name = "_".join(os.path.basename(r.path).split("_")[:3]) if r.path else ""
        row = {"trial": name, "status": "error" if r.error else "ok",
               "steps": int(m.get("step", 0)), METRIC: float(m.get(METRIC, math.nan)),
               "figure": float(m.get("figure", math.nan)), "train_s": float(m.get("time_total_s", math.nan))}
        row.update({k: r.config.get(k) for k in SEARCH_SPACE})
        rows.append(row)
    # ties (a budget too short to leave the base law scores 1.0 for every trial) go to the earlier trial: Tune lists
    # a restored search in another order, and the best trial must not depend on it
    return sorted(rows, key=lambda d: (math.isnan(d[METRIC]), d[METRIC], _trial_number(d["trial"])))


def _trial_number(name: str) -> int:
    """The trial's number, the last field of ``trainable_<id>_<number>`` (0 if the name has none)."""
    tail = name.rsplit("_", 1)[-1]
    return int(tail) if tail.isdigit() else 0


def best_config(settings: TuneSettings, rows: list[dict]) -> dict:
    """The best trial's settings as the JSON ``ehss train --config`` reads (Config fields)."""
    best = rows[0]
    hp = {k: best[k] for k in SEARCH_SPACE}
    cfg = settings.base_config(hp, 0, settings.out)
    keep = ("agent", "task", "n", "timesteps", "eval_freq", "eval_episodes", "eval_seconds", "checkpoint_freq",
            "n_envs", "hp")
    return {k: getattr(cfg, k) for k in keep}


def compare(settings: TuneSettings, hp: dict, executor: Executor) -> list[dict]:
    """Train the best config and the shipped recipe on :attr:`TuneSettings.compare_seeds` fresh seeds (after
    the search's own) at the search's budget, as executor jobs; one row per run with its kept policy's
    validation figure."""
    seeds = [settings.seed + 1 + i for i in range(settings.compare_seeds)]
    parent = os.path.join(settings.out, "compare")
    plans = [(name, settings.base_config(over, s, parent)) for name, over in (("tuned", hp), ("shipped", {}))
             for s in seeds]
    results = executor.map([seed_job(cfg) for _, cfg in plans], desc="compare", fresh_process=True)
    rows = []
    for (name, cfg), res in zip(plans, results):
        materialize(res)
        s = res["summary"]
        rows.append({"recipe": name, "seed": cfg.seed, "steps": s["timesteps"], "best_step": s["best_step"],
                     "validation_figure": s["best_validation"]["figure"],
                     "final_figure": s["final_validation"]["figure"], "wall_s": s["wall_s"], "run": s["run_name"]})
    return rows


def run_search(settings: TuneSettings, executor: Executor) -> dict:
    """Run (or resume) the search on ``executor``'s Ray connection; write ``trials.json``, ``best_config.json``
    and, with ``compare_seeds``, ``compare.json`` in ``out``; return {"trials", "best_config", "compare",
    "shipped"}."""
    executor.ray()  # Tune runs on the executor's cluster (or local instance)
    # the trials run in Ray's worker processes, whose working directory is not this one
    settings = dataclasses.replace(settings, out=os.path.abspath(settings.out))
    results = make_tuner(settings).fit()
    rows = trial_rows(results)
    if not rows or math.isnan(rows[0][METRIC]):
        raise RuntimeError(f"no trial reported a validation figure; see the trial logs in {settings.out}/search")
    best = best_config(settings, rows)
    out = {"trials": rows, "best_config": best, "compare": [],
           "shipped": {k: getattr(get_spec(AGENT), k) for k in SEARCH_SPACE}}
    atomic_write_text(os.path.join(settings.out, "trials.json"), json.dumps(rows, indent=1) + "\n")
    atomic_write_text(os.path.join(settings.out, "best_config.json"), json.dumps(best, indent=1) + "\n")
    if settings.compare_seeds:
        out["compare"] = compare(settings, best["hp"], executor)
        atomic_write_text(os.path.join(settings.out, "compare.json"), json.dumps(out["compare"], indent=1) + "\n")
    return out


__all__ = ["AGENT", "METRIC", "SEARCH_SPACE", "TuneSettings", "tune_space", "trainable", "make_tuner",
           "trial_rows", "best_config", "compare", "run_search"]
