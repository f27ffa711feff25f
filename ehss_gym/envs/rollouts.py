"""The one rollout loop: a policy on a fixed set of pinned episodes, side by side in the native vector env.

Every caller that runs a policy on given scenarios uses :func:`rollout`: the evaluation harness, the
training's held-out validation, the training report's analyses and the PID tuning. The episodes run as the
lanes of one :class:`~ehss_gym.envs.vector.EHSSTrackingVectorEnv` (autoreset disabled), so one compiled call
advances all of them, and the policy gets one batched ``predict`` per agent step, as SB3's
``evaluate_policy`` does for a vector env.
"""

from __future__ import annotations

import math
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


class SideBySide:
    """Several policies on consecutive lanes of one vector env: policy j acts for its ``n_j`` lanes, with its own
    recurrent state, and gets exactly those lanes' observations (the batch it would get alone).

    Policies of one class with a ``side_by_side(policies, n)`` static method (the safe-weights policies') may act
    together: where the parts have equal lane counts and that method returns an object, its ``predict(observation)``
    gives all the parts' deterministic actions in one call (one forward pass for several training seeds), the same
    actions as the parts' own calls.

    Args:
        parts: (policy, n) pairs, in lane order; each policy has SB3's ``predict``.
    """

    def __init__(self, parts):
        self.parts = [(policy, int(n)) for policy, n in parts]
        self._together = None if len({n for _, n in self.parts}) != 1 else _UNSET

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        """SB3's ``predict`` over all lanes: the parts' actions stacked in lane order; ``state`` a list of theirs."""
        states = [None] * len(self.parts) if state is None else state
        if deterministic and self._together is _UNSET:
            fit = getattr(type(self.parts[0][0]), "side_by_side", None)
            self._together = None if fit is None else fit([p for p, _ in self.parts], self.parts[0][1])
        if deterministic and self._together is not None:
            return self._together.predict(observation), states
        actions, new, s = [], [], 0
        for (policy, n), st in zip(self.parts, states):
            start = None if episode_start is None else episode_start[s:s + n]
            a, st = policy.predict(observation[s:s + n], state=st, episode_start=start, deterministic=deterministic)
            actions.append(np.asarray(a, dtype=np.float32).reshape(n, -1))
            new.append(st)
            s += n
        return np.concatenate(actions), new

    def fixed_action(self, n: int) -> np.ndarray | None:
        """The parts' fixed actions stacked, if every part has them (see :func:`rollout`); else None."""
        fixed = [getattr(policy, "fixed_action", None) for policy, _ in self.parts]
        if any(f is None for f in fixed):
            return None
        out = [f(m) for f, (_, m) in zip(fixed, self.parts)]
        return None if any(a is None for a in out) else np.concatenate(out)


_UNSET = object()  # SideBySide's joint predictor, before its first deterministic call


def _lane_dict(stacked: dict, i: int) -> dict:
    """Sub-env i's entry of a dict that the vector env stacked per key (Gymnasium's info convention)."""
    out = {}
    for k, v in stacked.items():
        if k.startswith("_"):
            continue
        x = _lane_dict(v, i) if isinstance(v, dict) else v[i]
        out[k] = x.item() if isinstance(x, np.generic) else x
    return out


# the reward terms whose constants come from the base law's run of each episode (a second simulation per episode)
BASE_RUN_REWARDS = ("class", "physical")


def _vector_env(env_kwargs: dict, count: int, venv: EHSSTrackingVectorEnv | None,
                returns: bool) -> EHSSTrackingVectorEnv:
    if venv is not None:
        if venv.num_envs != count or venv.metadata["autoreset_mode"] != AutoresetMode.DISABLED:
            raise ValueError(f"venv must be an EHSSTrackingVectorEnv of {count} sub-envs with autoreset disabled")
        return venv
    if not returns:  # the rewards are not wanted: skip the base law's runs that only their constants need
        rw = {**(env_kwargs.get("reward_weights") or {}), **{k: 0.0 for k in BASE_RUN_REWARDS}}
        env_kwargs = {**env_kwargs, "reward_weights": rw}
    return EHSSTrackingVectorEnv(count, autoreset_mode=AutoresetMode.DISABLED, **env_kwargs)


def rollout(policy, env_kwargs: dict, scenarios: Sequence, *, trace: bool = False, name: str = "policy",
            venv: EHSSTrackingVectorEnv | None = None, returns: bool = True) -> list[EpisodeResult]:
    """Run ``policy`` deterministically on pinned episodes, one lane each; results in the order given.

    Args:
        policy: an object with SB3's ``predict(obs, state=None, episode_start=None, deterministic=True)``
            taking a batch (N, D) of observations. Its recurrent ``state`` (a PID's integrator) is passed along
            for the whole batch, and every episode gets ``episode_start=True`` on its first step. A policy with a
            ``fixed_action(n)`` method that returns actions (n, dims) acts with them whatever it observes (a scripted
            law's zero residual): the env then runs up to :data:`HOLD_STEPS` agent steps per compiled call
            (:meth:`~ehss_gym.envs.vector.EHSSTrackingVectorEnv.step_held`), with the same results as step by step.
        env_kwargs: keyword arguments of the env the policy acts in (``EHSSTrackingEnv``'s).
        scenarios: one pinned episode per lane: a :class:`~ehss_gym.core.settings.Scenario` with the env's
            controller settings, or a dict of its physical fields.
        trace: record the agent-rate trace of every episode.
        name: the policy's name in error messages.
        venv: a vector env to reuse (``len(scenarios)`` sub-envs, autoreset disabled); default a new one.
        returns: sum the env's rewards into each result's ``ret``. False leaves ``ret`` NaN and builds the env
            without the reward terms that need the base law's run of every episode (:data:`BASE_RUN_REWARDS`, a
            second simulation of it): the loop, and so the metrics and traces, are the same bit for bit.

    Raises:
        RuntimeError: the policy gave an invalid (NaN or misshapen) action.
    """
    N = len(scenarios)
    if N == 0:
        return []
    env = _vector_env(env_kwargs, N, venv, returns)
    obs, _ = env.reset(options={"scenario": list(scenarios)})
    done = np.zeros(N, dtype=bool)
    results: list = [None] * N
    # the trace: per agent step the live lanes' trace columns, grouped by the set of live lanes (it only shrinks, as
    # ended lanes never restart), so memory follows the lanes still running; each lane's rows are cut out at the end
    epochs: list = []  # (live lanes, [arrays (steps, live lanes, columns)])
    info_ok = env._lanes.info_ok  # the lanes' last finite sample of the step (what the step's info shows)
    # a policy that acts the same whatever it observes runs HOLD_STEPS agent steps per compiled call
    fixed = getattr(policy, "fixed_action", None)
    held = None if fixed is None else fixed(N)
    record = np.zeros((HOLD_STEPS, N, layout.N_INFO)) if trace and held is not None else None
    episode_start = np.ones(N, dtype=bool)
    total = np.zeros(N)
    state = None
    steps = 0
    live = np.arange(N)  # the lanes still running, and (as a column) the rows of their trace samples
    rows = live[:, None]
    while len(live):
        if held is None:
            action, state = policy.predict(obs, state=state, episode_start=episode_start, deterministic=True)
            episode_start[:] = False
        try:
            if held is None:
                obs, reward, term, trunc, info = env.step(np.asarray(action, dtype=np.float32).reshape(N, -1))
                n = 1
            else:
                obs, reward, term, trunc, info, n = env.step_held(held, HOLD_STEPS, record=record)
        except ValueError as exc:
            raise RuntimeError(f"policy {name!r} gave an invalid action ({exc})") from None
        steps += n
        if len(live) == N:
            total += reward
        else:
            total[live] += reward[live]
        if trace:
            if not epochs or len(epochs[-1][0]) != len(live):
                epochs.append((live, []))
            epochs[-1][1].append(info_ok[rows, _TRACE_COLS][None] if record is None else
                                 record[:n, live][..., _TRACE_COLS])
        ending = (term | trunc)[live]
        if ending.any():
            for i in live[ending]:
                done[i] = True
                m = _lane_dict(info["metrics"], i)
                m["n_clipped"] = int(info["n_clipped"][i])
                m["agent_steps"] = steps
                results[i] = m
            live = np.flatnonzero(~done)
            rows = live[:, None]
    traces = _lane_traces(epochs, N) if trace else [None] * N
    return [EpisodeResult(results[i], traces[i], float(total[i]) if returns else math.nan) for i in range(N)]


HOLD_STEPS = 4096  # agent steps per call for a fixed policy (its trace's record: 4096 x N_INFO doubles per lane)
TRACE_KEYS = ("t", "e", "y_ref", "y", "r", "u", "friction")
# the info's columns (layout I_*) the trace is made of: t, e, y_d, the true error, r, u applied, friction
_TRACE_COLS = np.array([layout.I_T, layout.I_E, layout.I_YD, layout.I_E_TRUE, layout.I_R, layout.I_UAPP, layout.I_TF])


def _lane_traces(epochs: list, N: int) -> list[dict]:
    """Each lane's trace (TRACE_KEYS) from the rollout's epochs: (live lanes, [arrays (steps, live lanes, columns)])."""
    lane_rows: list = [[] for _ in range(N)]
    for live, chunks in epochs:
        block = np.concatenate(chunks)
        for j, i in enumerate(live):
            lane_rows[i].append(block[:, j])
    return [_trace(np.concatenate(rows or [np.zeros((0, len(_TRACE_COLS)))])) for rows in lane_rows]


def _trace(cols: np.ndarray) -> dict:
    """A lane's trace (TRACE_KEYS) from its rows of the info's trace columns (n, len(_TRACE_COLS))."""
    t, e, yd, e_true, r, u, tf = cols.T
    return {"t": t.copy(), "e": e.copy(), "y_ref": yd.copy(), "y": yd + e_true,  # the true output: y_d + (y - y_d)
            "r": r.copy(), "u": u.copy(), "friction": tf.copy()}
