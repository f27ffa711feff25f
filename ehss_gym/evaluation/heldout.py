"""Held-out evaluation used during training: the policy and the base law on the same fixed scenarios.

Scenarios come from :func:`ehss_gym.core.scenarios.heldout_scenarios`, whose seeds are disjoint from every
training seed. Model selection during training uses the *validation* block (held-out seeds from
:data:`VALIDATION_START` on), so the scenarios a run is selected on are not the ones it is finally
reported on (:data:`TEST_START`, the block the evaluation harness draws from as well).

Figures (lower is better; :mod:`ehss_gym.evaluation.scoring`'s ruler), over the scenarios:

- ``figure``: the overall figure G against the reference law (the CLF law with n = 2, zero residual, same
  scenarios; exactly 1 for the reference itself): per class (tracking, disturbance, effort on the noise-free
  scenarios, chatter on the noisy ones) G_c = exp(mean log q_c), G = exp(mean over the classes of log G_c).
  ``tracking``, ``disturbance``, ``effort``, ``chatter``: the class figures.
- ``failed`` and ``n_failed``: the failure gate (any diverged or lost-track scenario, or a mean saturation
  share above :data:`~ehss_gym.evaluation.scoring.SATURATION_GATE`) and the number of failed scenarios.
  :func:`selection_key` orders validations: no failure first, then fewer failed scenarios, then G; the
  checkpoint with the least key is kept.
- ``rel_tracking``, ``rel_disturbance``, ``rel_effort``, ``rel_chatter``: the class figures against the
  agent's own base law (the CLF law with the agent's n, zero residual) instead of the reference.

An undefined value (a class with no scenario, a mean over none) is None.
"""

from __future__ import annotations

import math

import numpy as np

from ehss_gym.core.scenarios import heldout_scenarios
from ehss_gym.envs import EnvConfig, rollout
from ehss_gym.envs.actions import action_dims, action_mode

from .scoring import CLASSES, PHYSICAL_FLOORS, Floors, episode_log_ratios, failure, figure_of, physical_floors, rank_key

VALIDATION_START = 5_000_000  # offset of the validation block among held-out seeds (the harness uses 0.. and 1e6..)
TEST_START = 0  # offset of the test block (the evaluation harness's held-out suite)


def heldout_suite(env_kwargs: dict, count: int, start: int, episode_seconds: float | None = None) -> list:
    """``count`` held-out Scenarios for the controller settings of ``env_kwargs`` (seeds from ``start``), drawn as the
    env draws its training episodes (with the unmodelled effects when ``unmodelled_effects`` is set, on
    ``unmodelled_share`` of them)."""
    cfg = EnvConfig.from_kwargs(env_kwargs)
    return heldout_scenarios(count, cfg.template(), episode_seconds, cfg.distribution(), start=start)


class _ActFn:
    """An ``act_fn`` (raw observations (B, D) -> actions (B, k)) as a policy with SB3's ``predict``."""

    def __init__(self, act_fn, k: int = 1):
        """Wrap ``act_fn`` (None: the zero action) of actions of size ``k``."""
        self.act_fn = act_fn
        self.k = k

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        """SB3-style: (actions (B, k) float32, state unchanged)."""
        if self.act_fn is None:  # the base law in residual mode
            return np.zeros((len(observation), self.k), dtype=np.float32), state
        return np.asarray(self.act_fn(observation), dtype=np.float32).reshape(len(observation), self.k), state


def run_episodes(env_kwargs: dict, scenarios: list, act_fn=None) -> list[dict]:
    """One episode per scenario through the rollout loop (:func:`ehss_gym.envs.rollouts.rollout`).

    Args:
        env_kwargs: ``EHSSTracking-v0`` keyword arguments (scenario pinned per episode).
        scenarios: Scenarios built from the env's ``scenario_template``.
        act_fn: raw observations (B, D) float32 -> actions (B, k); None = zero action (the base law in
            residual mode).

    Returns:
        The env's end-of-episode metrics dict per scenario (``info["metrics"]``), with the scenario's
        friction events, its task and the episode return added.
    """
    out = []
    cfg = EnvConfig.from_kwargs(env_kwargs)
    k = action_dims(action_mode(cfg.action), cfg.dob_hz)
    for sc, r in zip(scenarios, rollout(_ActFn(act_fn, k), env_kwargs, scenarios)):
        m = dict(r.metrics)
        m["return"] = r.ret
        m["has_friction"] = any(ev[0] > 0 for ev in sc.friction)
        m["noisy"] = any(v > 0.0 for v in sc.noise_std)
        m["task"] = sc.task
        out.append(m)
    return out


def floors_of(env_kwargs: dict) -> Floors:
    """The ruler's floors on the rig of an env's settings (its ``plant``; Table I's without one)."""
    return physical_floors(EnvConfig.from_kwargs(env_kwargs).plant)


def _class_logs(results: list[dict], reference: list[dict], floors: Floors) -> dict:
    """Per class the episodes' log ratios to ``reference`` (episodes where neither diverged)."""
    logs: dict = {c: [] for c in CLASSES}
    for m, ref in zip(results, reference):
        for c, v in episode_log_ratios(m, ref, m["noisy"], m["task"], floors).items():
            logs[c].append(v)
    return logs


def relative_scores(results: list[dict], base: list[dict], reference: list[dict] | None = None,
                    floors: Floors = PHYSICAL_FLOORS) -> dict:
    """The validation figures of ``results`` against ``reference`` (default ``base``) and its class figures
    against ``base`` (module docstring), with the failure gate and mean raw metrics; ``floors``: the ruler's on the
    rig the episodes ran on (:func:`floors_of`)."""
    reference = base if reference is None else reference
    g, gc = figure_of(_class_logs(results, reference, floors))
    failed, n_failed = failure(results)
    out = {"figure": g, "failed": failed, "n_failed": n_failed, "episodes": len(results),
           "diverged": sum(1 for m in results if m["diverged"])}
    out.update({c: gc.get(c, math.nan) for c in CLASSES})
    _, gb = figure_of(_class_logs(results, base, floors))
    out.update({f"rel_{c}": gb.get(c, math.nan) for c in CLASSES})
    for key in ("trk_rmse", "dst_peak", "tv_u_rate", "return"):
        v = [m[key] for m in results if not m["diverged"] and math.isfinite(m[key])]
        out[key] = float(np.mean(v)) if v else math.nan
    # undefined values (a class without an episode, a figure without a class) as None: the row goes into JSON files
    # that refuse NaN (the safe weights' metadata)
    return {k: None if isinstance(v, float) and math.isnan(v) else v for k, v in out.items()}


def _figure(row: dict) -> float:
    return math.nan if row["figure"] is None else float(row["figure"])


def selection_key(row: dict) -> tuple:
    """The order of validation rows (least = best): no failure first, then fewer failed scenarios, then the
    overall figure (an undefined figure last)."""
    return rank_key(row["failed"], row["n_failed"], _figure(row))


def tune_objective(row: dict) -> float:
    """One number for a hyperparameter search (lower is better): the overall figure of a validation row that
    passed the gate, inf for one that failed it or has no figure (every passing row ranks ahead, as
    :func:`selection_key` has it)."""
    g = _figure(row)
    return math.inf if row["failed"] or math.isnan(g) else g


def sb3_act_fn(model, vecnormalize=None):
    """Deterministic actions of an SB3 model on raw observations, normalised as during training."""

    def act(obs):
        """Deterministic actions (B, 1) for raw observations (B, D)."""
        o = vecnormalize.normalize_obs(obs) if vecnormalize is not None else obs
        return model.predict(o, deterministic=True)[0]

    return act


def policy_act_fn(policy):
    """Deterministic actions of any object with SB3's ``predict`` (e.g. a SafePolicy) on raw observations."""
    return lambda obs: policy.predict(obs, deterministic=True)[0]


__all__ = ["VALIDATION_START", "TEST_START", "heldout_suite", "run_episodes", "relative_scores", "floors_of",
           "selection_key",
           "tune_objective", "sb3_act_fn",
           "policy_act_fn"]
