"""Run bookkeeping for training: seed ranges, reproducible run names, checkpoints and RNG state.

None of this needs the env or torch (the CLI parses seeds and names runs before any training starts), so it is
tested on its own. The RNG states a checkpoint holds are captured by :mod:`ehss_gym.train.callbacks`.

Checkpoint layout (in ``<run>/checkpoints/``), written at a rollout boundary (after a PPO update, so
the saved parameters have learned from every counted step):

- ``step_<S>.zip``: the SB3 model (parameters, optimizer state, ``num_timesteps = S``);
- ``step_<S>_vecnormalize.pkl``: the VecNormalize statistics at step S;
- ``step_<S>_state.json``: RNG states (Python, NumPy, torch, every sub-env's generator) and the
  callbacks' state (evaluation history, best score, wall time so far);
- ``latest.json``: ``{"step": S, ...}``, written last and atomically; a checkpoint exists only once
  this file names it, so a kill -9 while writing leaves the previous checkpoint in force.
"""

from __future__ import annotations

import hashlib
import json
import os
import pickle
import re

from ehss_gym.infra.util import atomic_write, atomic_write_text

LATEST = "latest.json"
CKPT_DIR = "checkpoints"
KEEP_CHECKPOINTS = 2


class RunError(ValueError):
    """Bad training input (unknown agent, bad seed range, missing checkpoint, ...); the CLI exits with 2."""


# ---------------------------------------------------------------------------------------------------
# Seeds and names


def parse_seeds(text: str, limit: int = 10_000) -> list[int]:
    """Seeds from ``"3"``, ``"0-4"`` (inclusive) or a comma list of those (``"0-2,7"``).

    Args:
        text: the seed specification.
        limit: seeds must be integers in [0, limit).

    Returns:
        The seeds, sorted.

    Raises:
        RunError: a malformed item, a range with start > end, a seed outside [0, limit), a seed given twice
            (two runs of one seed would write one run folder), or no seeds.
    """
    if not isinstance(text, str) or not text.strip():
        raise RunError(f"--seeds must be like '0-4', '3' or '0-2,7' (integers in [0, {limit})), got {text!r}")
    seeds: set[int] = set()
    for item in text.split(","):
        item = item.strip()
        m = re.fullmatch(r"(\d+)(?:-(\d+))?", item)
        if not m:
            raise RunError(f"--seeds must be like '0-4', '3' or '0-2,7' (integers in [0, {limit})), got {text!r} "
                           f"(bad item {item!r})")
        a = int(m.group(1))
        b = int(m.group(2)) if m.group(2) is not None else a
        if a > b:
            raise RunError(f"--seeds range {item!r} has start > end; write it as '{b}-{a}'")
        if b >= limit:
            raise RunError(f"--seeds must be integers in [0, {limit}), got {b} in {text!r}")
        twice = seeds.intersection(range(a, b + 1))
        if twice:
            raise RunError(f"--seeds names seed {min(twice)} twice in {text!r}; give each seed once")
        seeds.update(range(a, b + 1))
    return sorted(seeds)


def config_hash(config: dict, exclude=()) -> str:
    """SHA-256 (hex) of the canonical JSON of ``config`` without the keys in ``exclude``."""
    d = {k: v for k, v in config.items() if k not in set(exclude)}
    blob = json.dumps(d, sort_keys=True, separators=(",", ":"), default=str).encode()
    return hashlib.sha256(blob).hexdigest()


def run_name(agent: str, task: str, n: int, seed: int, config: dict, exclude=()) -> str:
    """Reproducible run name ``<agent>_<task>_n<n>_s<seed>_<hash8>``.

    The hash covers every setting that changes the result (``config`` minus ``exclude``: output
    folder, progress bars, ...), so equal settings give equal names and any change gives a new one.
    """
    return f"{agent}_{task}_n{n}_s{seed}_{config_hash(config, exclude)[:8]}"


# ---------------------------------------------------------------------------------------------------
# Checkpoints


def checkpoint_dir(run_dir: str) -> str:
    """``<run>/checkpoints``."""
    return os.path.join(run_dir, CKPT_DIR)


def checkpoint_files(run_dir: str, step: int) -> dict[str, str]:
    """Paths of the checkpoint at ``step``."""
    d = checkpoint_dir(run_dir)
    return {"model": os.path.join(d, f"step_{step}.zip"),
            "vecnormalize": os.path.join(d, f"step_{step}_vecnormalize.pkl"),
            "state": os.path.join(d, f"step_{step}_state.json")}


def latest_checkpoint(run_dir: str) -> dict | None:
    """The manifest of the newest complete checkpoint (``{"step", "model", "vecnormalize", "state"}``), or None."""
    path = os.path.join(checkpoint_dir(run_dir), LATEST)
    if not os.path.isfile(path):
        return None
    try:
        with open(path, encoding="utf-8") as f:
            man = json.load(f)
        step = int(man["step"])
    except (ValueError, KeyError, TypeError, OSError):
        raise RunError(f"checkpoint manifest {path} is unreadable; delete it to start over") from None
    files = checkpoint_files(run_dir, step)
    missing = [p for p in files.values() if not os.path.isfile(p)]
    if missing:
        raise RunError(f"checkpoint manifest {path} names step {step} but {missing} are missing")
    return {"step": step, **files}


def save_checkpoint(run_dir: str, step: int, model, vecnormalize, state: dict) -> dict:
    """Write the checkpoint of ``step`` (model, VecNormalize, state) and then point ``latest.json`` at it.

    Every file is written to a temporary name and renamed, so an interrupted save never replaces a
    good checkpoint with a partial one. Older checkpoints beyond :data:`KEEP_CHECKPOINTS` are deleted.
    """
    files = checkpoint_files(run_dir, step)
    os.makedirs(checkpoint_dir(run_dir), exist_ok=True)
    atomic_write(files["model"], lambda f: model.save(f))
    atomic_write(files["vecnormalize"], lambda f: pickle.dump(vecnormalize, f))  # as VecNormalize.save does
    atomic_write_text(files["state"], json.dumps(state))
    atomic_write_text(os.path.join(checkpoint_dir(run_dir), LATEST),
                      json.dumps({"step": int(step), **{k: os.path.basename(v) for k, v in files.items()}}))
    prune_checkpoints(run_dir, keep=KEEP_CHECKPOINTS)
    return {"step": step, **files}


def checkpoint_steps(run_dir: str) -> list[int]:
    """Steps of the checkpoint model files present (complete or not), ascending."""
    d = checkpoint_dir(run_dir)
    if not os.path.isdir(d):
        return []
    steps = []
    for fn in os.listdir(d):
        m = re.fullmatch(r"step_(\d+)\.zip", fn)
        if m:
            steps.append(int(m.group(1)))
    return sorted(steps)


def prune_checkpoints(run_dir: str, keep: int = KEEP_CHECKPOINTS) -> None:
    """Delete all but the newest ``keep`` checkpoints, never the one ``latest.json`` names."""
    man = latest_checkpoint(run_dir)
    current = man["step"] if man else None
    steps = checkpoint_steps(run_dir)
    for s in steps[:-keep] if keep > 0 else steps:
        if s == current:
            continue
        for p in checkpoint_files(run_dir, s).values():
            if os.path.exists(p):
                os.unlink(p)


def read_state(path: str) -> dict:
    """The JSON state file of a checkpoint (RNG states, the callbacks' state)."""
    with open(path, encoding="utf-8") as f:
        return json.load(f)


__all__ = ["RunError", "parse_seeds", "config_hash", "run_name", "latest_checkpoint",
           "save_checkpoint", "checkpoint_files", "checkpoint_steps", "prune_checkpoints", "read_state"]
