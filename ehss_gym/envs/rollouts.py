"""The one rollout loop: a policy on a fixed set of pinned episodes, side by side in the native vector env.

Every caller that runs a policy on given scenarios uses :func:`rollout`: the evaluation harness, the
training's held-out validation, the training report's analyses and the PID tuning. The episodes run as the
lanes of one :class:`~ehss_gym.envs.vector.EHSSTrackingVectorEnv` (autoreset disabled), so one compiled call
advances all of them, and the policy gets one batched ``predict`` per agent step, as SB3's
``evaluate_policy`` does for a vector env.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from gymnasium.vector import AutoresetMode

from ehss_gym.core import layout

from .vector import EHSSTrackingVectorEnv


@dataclass
class EpisodeResult:
    """What one episode of a rollout gave.

    Attributes:
        metrics: the env's core metrics summary of the episode (``info["metrics"]``), plus ``n_clipped``
            (out-of-range actions) and ``agent_steps``.
        trace: per agent step (if asked for), at the step's last control sample: t [s], e (as measured), y_ref
            (the reference model's output), y (the plant's true output), r (the raw reference) [output unit],
            u (applied) [mA] and friction [N*m]; None otherwise.
        ret: the episode's return (sum of the env's rewards) [-].
    """

    metrics: dict
    trace: dict | None = field(default=None, repr=False)
    ret: float = 0.0


def _lane_dict(stacked: dict, i: int) -> dict:
    """Sub-env i's entry of a dict that the vector env stacked per key (Gymnasium's info convention)."""
    out = {}
    for k, v in stacked.items():
        if k.startswith("_"):
            continue
        x = _lane_dict(v, i) if isinstance(v, dict) else v[i]
        out[k] = x.item() if isinstance(x, np.generic) else x
    return out


def _vector_env(env_kwargs: dict, count: int, venv: EHSSTrackingVectorEnv | None) -> EHSSTrackingVectorEnv:
    if venv is not None:
        if venv.num_envs != count or venv.metadata["autoreset_mode"] != AutoresetMode.DISABLED:
            raise ValueError(f"venv must be an EHSSTrackingVectorEnv of {count} sub-envs with autoreset disabled")
        return venv
    return EHSSTrackingVectorEnv(count, autoreset_mode=AutoresetMode.DISABLED, **env_kwargs)


def rollout(policy, env_kwargs: dict, scenarios: Sequence, *, trace: bool = False, name: str = "policy",
            venv: EHSSTrackingVectorEnv | None = None) -> list[EpisodeResult]:
    """Run ``policy`` deterministically on pinned episodes, one lane each; results in the order given.

    Args:
        policy: an object with SB3's ``predict(obs, state=None, episode_start=None, deterministic=True)``
            taking a batch (N, D) of observations. Its recurrent ``state`` (a PID's integrator) is passed along
            for the whole batch, and every episode gets ``episode_start=True`` on its first step.
        env_kwargs: keyword arguments of the env the policy acts in (``EHSSTrackingEnv``'s).
        scenarios: one pinned episode per lane: a :class:`~ehss_gym.core.settings.Scenario` with the env's
            controller settings, or a dict of its physical fields.
        trace: record the agent-rate trace of every episode.
        name: the policy's name in error messages.
        venv: a vector env to reuse (``len(scenarios)`` sub-envs, autoreset disabled); default a new one.

    Raises:
        RuntimeError: the policy gave an invalid (NaN or misshapen) action.
    """
    N = len(scenarios)
    if N == 0:
        return []
    env = _vector_env(env_kwargs, N, venv)
    obs, _ = env.reset(options={"scenario": list(scenarios)})
    done = np.zeros(N, dtype=bool)
    results: list = [None] * N
    traces = [{k: [] for k in TRACE_KEYS} for _ in range(N)] if trace else None
    info_ok = env._lanes.info_ok  # the lanes' last finite sample of the step (what the step's info shows)
    episode_start = np.ones(N, dtype=bool)
    returns = np.zeros(N)
    state = None
    steps = 0
    while not done.all():
        action, state = policy.predict(obs, state=state, episode_start=episode_start, deterministic=True)
        episode_start[:] = False
        steps += 1
        try:
            obs, reward, term, trunc, info = env.step(np.asarray(action, dtype=np.float32).reshape(N, -1))
        except ValueError as exc:
            raise RuntimeError(f"policy {name!r} gave an invalid action ({exc})") from None
        live = np.flatnonzero(~done)
        returns[live] += reward[live]
        if trace:
            for i in live:
                _record(traces[i], info_ok[i])
        for i in live[(term | trunc)[live]]:
            done[i] = True
            m = _lane_dict(info["metrics"], i)
            m["n_clipped"] = int(info["n_clipped"][i])
            m["agent_steps"] = steps
            results[i] = m
    out = []
    for i in range(N):
        tr = {k: np.asarray(v, dtype=np.float64) for k, v in traces[i].items()} if trace else None
        out.append(EpisodeResult(results[i], tr, float(returns[i])))
    return out


TRACE_KEYS = ("t", "e", "y_ref", "y", "r", "u", "friction")


def _record(tr: dict, i: np.ndarray) -> None:
    """Append one agent step's sample (a lane's info row, layout I_*) to a trace."""
    tr["t"].append(float(i[layout.I_T]))
    tr["e"].append(float(i[layout.I_E]))
    tr["y_ref"].append(float(i[layout.I_YD]))
    tr["y"].append(float(i[layout.I_YD] + i[layout.I_E_TRUE]))  # the true output: y_d + (y - y_d)
    tr["r"].append(float(i[layout.I_R]))
    tr["u"].append(float(i[layout.I_UAPP]))
    tr["friction"].append(float(i[layout.I_TF]))
