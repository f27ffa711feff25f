"""SB3 callbacks of the training script: progress bar, held-out evaluation with best-model keeping,
checkpoints at rollout boundaries (with the RNG states: :func:`capture_rng`, :func:`restore_rng`), and the
wall-time clock.

All custom behaviour of training lives here, so :mod:`ehss_gym.train.loop` stays a plain script.
Callbacks that carry state across an interruption expose ``state_dict()`` / ``load_state_dict()``;
:class:`Checkpoint` stores those in the checkpoint and the resume path restores them.
"""

from __future__ import annotations

import csv
import io
import json
import os
import pickle
import random
import shutil
import time
from collections.abc import Callable

import numpy as np
import torch
from stable_baselines3.common.callbacks import BaseCallback
from tqdm.auto import tqdm

from ehss_gym.evaluation.heldout import (
    floors_of,
    relative_scores,
    run_episodes,
    sb3_act_fn,
    selection_key,
    tune_objective,
)
from ehss_gym.infra.util import atomic_write, atomic_write_text

from . import runs

# ---------------------------------------------------------------------------------------------------
# RNG state (stored in each checkpoint)


def capture_rng(env_rngs=()) -> dict:
    """JSON-able states of Python's, NumPy's and torch's global RNGs and of the given Generators."""
    py = random.getstate()
    npst = np.random.get_state()
    return {
        "python": [py[0], list(py[1]), py[2]],
        "numpy": [npst[0], npst[1].tolist(), int(npst[2]), int(npst[3]), float(npst[4])],
        "torch": torch.get_rng_state().tolist(),
        "envs": [g.bit_generator.state for g in env_rngs],
    }


def restore_rng(state: dict, env_rngs=()) -> None:
    """Inverse of :func:`capture_rng` (``env_rngs`` must be Generators of the same bit generators)."""
    py = state["python"]
    random.setstate((py[0], tuple(py[1]), py[2]))
    n = state["numpy"]
    np.random.set_state((n[0], np.asarray(n[1], dtype=np.uint32), n[2], n[3], n[4]))
    torch.set_rng_state(torch.tensor(state["torch"], dtype=torch.uint8))
    envs = state.get("envs", [])
    if envs and len(envs) != len(env_rngs):
        raise runs.RunError(f"checkpoint holds {len(envs)} env RNG states but the run has {len(env_rngs)} envs")
    for g, s in zip(env_rngs, envs):
        g.bit_generator.state = s


# ---------------------------------------------------------------------------------------------------
# Callbacks


class WallClock(BaseCallback):
    """Training wall time [s] and this process's CPU time [s] (on a shared machine the wall time measures the load as
    much as the run), accumulated across resumed segments and logged to TensorBoard."""

    def __init__(self):
        super().__init__()
        self.previous = 0.0  # seconds of earlier segments (restored on resume)
        self.previous_cpu = 0.0
        self._t0 = time.perf_counter()
        self._c0 = time.process_time()

    @property
    def seconds(self) -> float:
        """Wall time of this and the earlier segments [s]."""
        return self.previous + time.perf_counter() - self._t0

    @property
    def cpu_seconds(self) -> float:
        """CPU time of this process in this segment and the earlier segments' [s] (all its threads)."""
        return self.previous_cpu + time.process_time() - self._c0

    def _on_training_start(self) -> None:
        self._t0 = time.perf_counter()
        self._c0 = time.process_time()

    def _on_rollout_end(self) -> None:
        self.logger.record("time/wall_s", self.seconds)
        self.logger.record("time/cpu_s", self.cpu_seconds)

    def _on_step(self) -> bool:
        return True

    def state_dict(self) -> dict:
        """What a checkpoint stores: the wall and CPU time so far [s]."""
        return {"seconds": self.seconds, "cpu_seconds": self.cpu_seconds}

    def load_state_dict(self, d: dict) -> None:
        """Continue from a checkpoint's :meth:`state_dict`."""
        self.previous = float(d["seconds"])
        self.previous_cpu = float(d.get("cpu_seconds", 0.0))  # (a checkpoint written before the CPU time: 0)
        self._t0 = time.perf_counter()
        self._c0 = time.process_time()


class ProgressBar(BaseCallback):
    """A tqdm bar over agent steps, starting at the resumed step count."""

    def __init__(self, total: int, desc: str = "train", disable: bool = False):
        super().__init__()
        self.total = int(total)
        self.desc = desc
        self.disable = disable
        self.bar = None

    def _on_training_start(self) -> None:
        self.bar = tqdm(total=self.total, initial=self.num_timesteps, desc=self.desc, unit="step",
                        disable=self.disable, dynamic_ncols=True, smoothing=0.05)

    def _on_step(self) -> bool:
        self.bar.update(self.num_timesteps - self.bar.n)
        return True

    def _on_training_end(self) -> None:
        self.bar.update(self.num_timesteps - self.bar.n)
        self.bar.close()


class HeldoutEval(BaseCallback):
    """Every ``eval_freq`` steps (at a rollout boundary), score the deterministic policy on the validation
    scenarios against the base law, log it, and keep a copy of every new best model.

    Best candidates are kept as ``<run>/evals/best_step_<S>/`` (model.zip, vecnormalize.pkl); the
    history is ``<run>/evaluations.csv`` and ``.json``. At the end, :meth:`best_dir` names the best.
    """

    def __init__(self, run_dir: str, env_kwargs: dict, scenarios: list, base: list[dict], reference: list[dict],
                 eval_freq: int, wall: WallClock, on_eval: Callable[[dict], None] | None = None):
        """Evaluate every ``eval_freq`` steps on ``scenarios``; ``on_eval(row)`` is told each history row (with
        ``best_objective``, :func:`~ehss_gym.evaluation.heldout.tune_objective` of the best so far: ``ehss tune``
        reports it to Ray Tune)."""
        super().__init__()
        self.on_eval = on_eval
        self.run_dir = run_dir
        self.env_kwargs = env_kwargs
        self.scenarios = scenarios
        self.base = base
        self.reference = reference
        self.eval_freq = int(eval_freq)
        self.wall = wall
        self.history: list[dict] = []
        self.best_row: dict | None = None
        self.best_step: int | None = None
        self.last_eval = -1

    # evaluation happens after the PPO update (rollout start), so the step count is honest
    def _on_training_start(self) -> None:
        if self.last_eval < 0:
            self.evaluate()

    def _on_rollout_start(self) -> None:
        if self.num_timesteps - self.last_eval >= self.eval_freq:
            self.evaluate()

    def _on_training_end(self) -> None:
        if self.num_timesteps != self.last_eval:
            self.evaluate()

    def _on_step(self) -> bool:
        return True

    def evaluate(self) -> dict:
        """Score the deterministic policy now; log it, keep it if it is the best so far; the history row."""
        vn = self.model.get_vec_normalize_env()
        t0 = time.perf_counter()
        results = run_episodes(self.env_kwargs, self.scenarios, sb3_act_fn(self.model, vn))
        row = relative_scores(results, self.base, self.reference, floors_of(self.env_kwargs))
        row.update(step=int(self.num_timesteps), wall_s=round(self.wall.seconds, 3),
                   cpu_s=round(self.wall.cpu_seconds, 3), eval_s=round(time.perf_counter() - t0, 3))
        self.last_eval = self.num_timesteps
        self.history.append(row)
        for k in ("figure", "n_failed", "tracking", "disturbance", "effort", "chatter", "rel_tracking",
                  "rel_disturbance", "trk_rmse", "dst_peak", "return", "diverged"):
            self.logger.record(f"heldout/{k}", row[k])
        if self.best_row is None or selection_key(row) < selection_key(self.best_row):
            self.best_row = row
            self.best_step = row["step"]
            self._save_best(row["step"])
        self.write_history()
        if self.on_eval is not None:
            self.on_eval({**row, "best_objective": tune_objective(self.best_row)})
        return row

    def _save_best(self, step: int) -> None:
        d = os.path.join(self.run_dir, "evals", f"best_step_{step}")
        os.makedirs(d, exist_ok=True)
        atomic_write(os.path.join(d, "model.zip"), lambda f: self.model.save(f))
        vn = self.model.get_vec_normalize_env()
        atomic_write(os.path.join(d, "vecnormalize.pkl"), lambda f: pickle.dump(vn, f))

    def best_dir(self) -> str | None:
        """The folder of the best model so far (``<run>/evals/best_step_<S>``), or None before any evaluation."""
        return None if self.best_step is None else os.path.join(self.run_dir, "evals", f"best_step_{self.best_step}")

    def write_history(self) -> None:
        """Write ``evaluations.csv`` and ``evaluations.json`` (one row per evaluation)."""
        if not self.history:
            return
        keys = list(self.history[0])
        buf = io.StringIO()
        w = csv.DictWriter(buf, fieldnames=keys)
        w.writeheader()
        w.writerows(self.history)
        atomic_write_text(os.path.join(self.run_dir, "evaluations.csv"), buf.getvalue())
        atomic_write_text(os.path.join(self.run_dir, "evaluations.json"), json.dumps(self.history, indent=1))

    def state_dict(self) -> dict:
        """What a checkpoint stores: the history, the best step, the step of the last evaluation."""
        return {"history": self.history, "best_step": self.best_step, "last_eval": self.last_eval}

    def load_state_dict(self, d: dict, checkpoint_step: int) -> None:
        """Restore the state saved at ``checkpoint_step``; best candidates saved after it are dropped."""
        self.history = list(d["history"])
        self.best_step = d["best_step"]
        self.best_row = next((r for r in self.history if r["step"] == self.best_step), None)
        self.last_eval = int(d["last_eval"])
        evals = os.path.join(self.run_dir, "evals")
        if os.path.isdir(evals):
            for fn in os.listdir(evals):
                if fn.startswith("best_step_") and int(fn.rsplit("_", 1)[1]) > checkpoint_step:
                    shutil.rmtree(os.path.join(evals, fn))
        self.write_history()


class Checkpoint(BaseCallback):
    """Save a checkpoint (see :mod:`ehss_gym.train.runs`) every ``freq`` steps, at a rollout boundary.

    The save happens at the start of a rollout, i.e. after the PPO update of the previous one, so the
    saved parameters have learned from all ``num_timesteps`` counted steps and a resume loses at most
    the steps collected since this checkpoint.
    """

    def __init__(self, run_dir: str, freq: int, stateful: dict, env_rngs):
        super().__init__()
        self.run_dir = run_dir
        self.freq = int(freq)
        self.stateful = stateful  # name -> callback with state_dict()
        self.env_rngs = env_rngs  # callable returning the sub-envs' Generators
        self.last = 0

    def _on_training_start(self) -> None:
        self.last = self.num_timesteps

    def _on_rollout_start(self) -> None:
        if self.num_timesteps - self.last >= self.freq:
            self.save()

    def _on_step(self) -> bool:
        return True

    def save(self) -> dict:
        """Write a checkpoint now (model, VecNormalize, RNG and callback states); its manifest."""
        # the model's counter, not the callback's copy: that one is only refreshed inside learn(), so a save
        # outside it (the end of a run) would be labelled step 0 and a later resume would drop every best model
        step = int(self.model.num_timesteps)
        state = {"num_timesteps": step, "rng": capture_rng(self.env_rngs()),
                 "callbacks": {k: cb.state_dict() for k, cb in self.stateful.items()}}
        man = runs.save_checkpoint(self.run_dir, step, self.model, self.model.get_vec_normalize_env(), state)
        self.last = step
        return man


__all__ = ["capture_rng", "restore_rng", "WallClock", "ProgressBar", "HeldoutEval", "Checkpoint"]
