"""Training as executor jobs (:mod:`ehss_gym.infra.execution`): one job per seed, run by ``ehss train --seeds``
and ``ehss tune`` on the local or the Ray backend.

A job trains one :class:`~ehss_gym.train.config.Config` (its seed passed explicitly) into its run folder, with
the run's output in ``<run>/train.log``, and returns plain data: the run's summary and the bytes of its
safe-weights files (``best/`` and ``final/``: ``policy.safetensors`` + ``policy.json``). When the job ran on
another machine, :func:`materialize` writes those files into the run folder here, so the trained policies
arrive without a shared file system and without a pickle. A job retried after its worker died finds the run's
last checkpoint and resumes from it.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os

from ehss_gym.infra.execution import Job
from ehss_gym.infra.util import atomic_write

from . import runs
from .config import Config
from .loop import describe, train

WEIGHT_FILES = tuple(f"{kind}/policy.{ext}" for kind in ("best", "final") for ext in ("safetensors", "json"))
# what does not change a run's result: left out of its job's content address (resume is decided by the job)
NOT_IN_KEY = ("resume", "progress", "seed")


def job_config(cfg: Config) -> dict:
    """The plain-data config of ``cfg``'s job: its fields without :data:`NOT_IN_KEY`, the run folder absolute
    (a Ray worker's working directory is not this one's)."""
    d = {k: v for k, v in dataclasses.asdict(cfg).items() if k not in NOT_IN_KEY}
    d["out"] = os.path.abspath(cfg.run_dir())
    return d


def train_job(config: dict, seed: int, context) -> dict:
    """Train one seed (an executor job); resumes from the run folder's checkpoint if it has one (a retry).

    Returns:
        {"summary": the run's summary dict, "weights": {relative path: file bytes} of :data:`WEIGHT_FILES`}.
    """
    cfg = Config(**config, seed=seed, progress=False)
    cfg = dataclasses.replace(cfg, resume=runs.latest_checkpoint(cfg.out) is not None)
    os.makedirs(cfg.out, exist_ok=True)
    with open(os.path.join(cfg.out, "train.log"), "a", encoding="utf-8") as log, \
            contextlib.redirect_stdout(log), contextlib.redirect_stderr(log):
        summary = train(cfg)
        print(describe(summary))  # what python -m ehss_gym.train.loop prints at the end
    weights = {}
    for rel in WEIGHT_FILES:
        with open(os.path.join(cfg.out, rel), "rb") as f:
            weights[rel] = f.read()
    return {"summary": summary, "weights": weights}


def seed_job(cfg: Config) -> Job:
    """The executor job that trains ``cfg``."""
    return Job(train_job, job_config(cfg), cfg.seed, label=cfg.run_name())


def materialize(result: dict) -> list[str]:
    """Write a job's safe-weights files into its run folder where they are missing (the job ran on another
    machine); the paths written."""
    run_dir = result["summary"]["run_dir"]
    written = []
    for rel, data in result["weights"].items():
        path = os.path.join(run_dir, rel)
        if not os.path.isfile(path):
            atomic_write(path, lambda f, data=data: f.write(data))
            written.append(path)
    return written


__all__ = ["WEIGHT_FILES", "NOT_IN_KEY", "job_config", "train_job", "seed_job", "materialize"]
