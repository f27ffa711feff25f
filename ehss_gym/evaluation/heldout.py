"""Held-out evaluation used during training: the policy and the base law on the same fixed scenarios.

Scenarios come from :func:`ehss_gym.core.scenarios.heldout_scenarios`, whose seeds are disjoint from every
training seed. Model selection during training uses the *validation* block (held-out seeds from
:data:`VALIDATION_START` on), so the scenarios a run is selected on are not the ones it is finally
reported on (:data:`TEST_START`, the block the evaluation harness draws from as well).

Scores (lower is better), per scenario i:

- ``score``: the evaluation harness's primary score (:func:`ehss_gym.evaluation.scoring.primary_score`),
  ``0.5 RMSE_i / RMSE_ref,i + 0.5 TV_i / TV_ref,i`` against the reference law (the CLF law with n = 2,
  zero residual, same scenario; 1 for the reference itself, 10 for a diverged episode); the mean over
  the scenarios picks the checkpoint to keep.
- ``rel_rmse``, ``rel_fric``, ``rel_tv``: RMSE, max |e| in the friction windows (scenarios with
  friction only) and control TV rate over those of the agent's own base law (the CLF law with the
  agent's n, zero residual), averaged over the scenarios.
"""

from __future__ import annotations

import math

import numpy as np

from ehss_gym.core.scenarios import heldout_scenarios
from ehss_gym.envs import EnvConfig, rollout

from .scoring import RMSE_FLOOR, SCORE_CAP, TV_FLOOR, primary_score

VALIDATION_START = 5_000_000  # offset of the validation block among held-out seeds (the harness uses 0.. and 1e6..)
TEST_START = 0  # offset of the test block (the evaluation harness's held-out suite)


def heldout_suite(env_kwargs: dict, count: int, start: int, episode_seconds: float | None = None) -> list:
    """``count`` held-out Scenarios for the controller settings of ``env_kwargs`` (seeds from ``start``)."""
    return heldout_scenarios(count, EnvConfig.from_kwargs(env_kwargs).template(), episode_seconds, start=start)


class _ActFn:
    """An ``act_fn`` (raw observations (B, D) -> actions (B, 1)) as a policy with SB3's ``predict``."""

    def __init__(self, act_fn):
        """Wrap ``act_fn`` (None: the zero action)."""
        self.act_fn = act_fn

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        """SB3-style: (actions (B, 1) float32, state unchanged)."""
        if self.act_fn is None:  # the base law in residual mode
            return np.zeros((len(observation), 1), dtype=np.float32), state
        return np.asarray(self.act_fn(observation), dtype=np.float32).reshape(len(observation), 1), state


def run_episodes(env_kwargs: dict, scenarios: list, act_fn=None) -> list[dict]:
    """One episode per scenario through the rollout loop (:func:`ehss_gym.envs.rollouts.rollout`).

    Args:
        env_kwargs: ``EHSSTracking-v0`` keyword arguments (scenario pinned per episode).
        scenarios: Scenarios built from the env's ``scenario_template``.
        act_fn: raw observations (B, D) float32 -> actions (B, 1); None = zero action (the base law in
            residual mode).

    Returns:
        The env's end-of-episode metrics dict per scenario (``info["metrics"]``), with the scenario's
        friction events and the episode return added.
    """
    out = []
    for sc, r in zip(scenarios, rollout(_ActFn(act_fn), env_kwargs, scenarios)):
        m = dict(r.metrics)
        m["return"] = r.ret
        m["has_friction"] = any(ev[0] > 0 for ev in sc.friction)
        out.append(m)
    return out


def relative_scores(results: list[dict], base: list[dict], reference: list[dict] | None = None) -> dict:
    """Mean primary score against ``reference`` (default ``base``) and ratios to ``base`` (module docstring)."""
    reference = base if reference is None else reference
    sc, rr, rf, rt, div = [], [], [], [], 0
    for m, b, ref in zip(results, base, reference):
        sc.append(primary_score(m["rmse"], m["tv_u_rate"], ref["rmse"], ref["tv_u_rate"], m["diverged"]))
        if m["diverged"]:
            div += 1
            rr.append(SCORE_CAP)
            rt.append(SCORE_CAP)
            if b["has_friction"]:
                rf.append(SCORE_CAP)
            continue
        rr.append(m["rmse"] / max(b["rmse"], RMSE_FLOOR))
        rt.append(m["tv_u_rate"] / max(b["tv_u_rate"], TV_FLOOR))
        if b["has_friction"] and math.isfinite(b["max_abs_e_friction"]) and math.isfinite(m["max_abs_e_friction"]):
            rf.append(m["max_abs_e_friction"] / max(b["max_abs_e_friction"], RMSE_FLOOR))
    out = {"score": float(np.mean(sc)), "rel_rmse": float(np.mean(rr)), "rel_fric": float(np.mean(rf)) if rf else 1.0,
           "rel_tv": float(np.mean(rt)), "diverged": div, "episodes": len(results)}
    out["rmse"] = float(np.mean([m["rmse"] for m in results]))
    fr = [m["max_abs_e_friction"] for m in results if m["has_friction"]]
    out["max_abs_e_friction"] = float(np.nanmean(fr)) if fr else math.nan
    out["tv_u_rate"] = float(np.mean([m["tv_u_rate"] for m in results]))
    out["return"] = float(np.mean([m["return"] for m in results]))
    return out


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


__all__ = ["VALIDATION_START", "TEST_START", "heldout_suite", "run_episodes", "relative_scores", "sb3_act_fn",
           "policy_act_fn"]
