"""An SB3 ``VecEnv`` over the native vector env: training steps all its envs in one compiled call.

:class:`NativeVecEnv` replaces ``DummyVecEnv([lambda: Monitor(gym.make("EHSSTracking-v0", **env_kwargs))] * n)``
and gives what that gives for the same seeds, bit for bit: the lanes of
:class:`~ehss_gym.envs.vector.EHSSTrackingVectorEnv` run the single env's kernel, sub-env i is seeded
``seed + i`` at the first reset after :meth:`seed` (SB3's ``VecEnv.seed``, which ``PPO(seed=...)`` calls),
and an ended episode is reset in the same step from the lane's own generator, which draws the next scenario
as the single env's ``reset()`` does. What SB3 and its wrappers read is as DummyVecEnv and Monitor give it:

- rewards as float32 (DummyVecEnv's buffer), dones = terminated or truncated;
- ``infos`` a list of one dict per sub-env: the env's step info (``t``, ``e``, ``s``, ``V``, ``u_base``,
  ``u_residual``, ``u_applied`` [mA], ``saturated``, ``sat_fraction``, ``friction_torque`` [N*m], ``clipped``,
  ``n_clipped``, ``diverged``), ``TimeLimit.truncated``, and at the end of an episode ``metrics``,
  ``terminal_observation``, ``episode`` (Monitor's ``{"r": return, "l": length [agent steps], "t": wall time
  since the env was made [s]}``) and, after a divergence, ``divergence_reason`` and ``t_diverged`` [s];
- ``reset_infos[i]``: the reset info of sub-env i's current episode (``scenario``, ``scenario_name``, ...).

The vector env runs with autoreset disabled: this adapter resets the ended lanes itself (``reset_mask``), so
SB3 sees its own convention (the step that ends an episode returns the next episode's first observation).
``get_attr`` / ``env_method`` act on the native vector env, which holds all lanes (``np_random`` is per lane:
each sub-env's scenario generator, as ``env.np_random`` of a single env).
"""

from __future__ import annotations

import functools
import time
from collections.abc import Sequence

import gymnasium as gym
import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import VecEnv

from ehss_gym.envs import EHSSTrackingVectorEnv


def lane_infos(stacked: dict, n: int, lanes: Sequence[int] | None = None) -> list[dict]:
    """Gymnasium's stacked vector infos (arrays with ``_key`` masks) as one dict per sub-env.

    Args:
        stacked: the info dict of a vector env's ``step`` or ``reset``.
        n: the number of sub-envs.
        lanes: the sub-envs to convert (default all); the others get an empty dict.

    Returns:
        ``n`` dicts of Python values; a key is in sub-env i's dict where its mask is set for i.
    """
    lanes = range(n) if lanes is None else list(lanes)
    full, partial = [], []  # keys every converted lane has (one list conversion each), and the others
    every_of: dict = {}  # the vector env's step keys share one mask: checked once
    for key, val in stacked.items():
        if not key.startswith("_"):
            mask = stacked.get("_" + key)
            every = every_of.get(id(mask))
            if every is None:
                every = every_of[id(mask)] = mask is None or False not in mask.tolist()  # (faster than mask.all())
            (full if every and not isinstance(val, dict) else partial).append((key, val, mask))
    if full:  # Python scalars, a row per lane, each made into its dict by one dict display
        out = _row_dicts(tuple(key for key, _, _ in full))(zip(*[val.tolist() for _, val, _ in full]))
    else:
        out = [{} for _ in range(n)]
    if len(lanes) < n:
        out = [d if i in lanes else {} for i, d in enumerate(out)]
    for key, val, mask in partial:
        has = [i for i in lanes if mask is None or mask[i]]
        sub = lane_infos(val, n, has) if isinstance(val, dict) else None
        for i in has:
            out[i][key] = sub[i] if sub is not None else val[i].item() if isinstance(val[i], np.generic) else val[i]
    if partial:  # keep the keys in the vector env's order
        order = [key for key in stacked if not key.startswith("_")]
        out = [{key: d[key] for key in order if key in d} for d in out]
    return out


@functools.lru_cache(maxsize=64)
def _row_dicts(keys: tuple):
    """A function of rows of values that makes each row a dict with ``keys`` in order: for string keys, a dict display
    written for them once (it builds a dict in about half the time of ``dict(zip(keys, row))``, which was the largest
    part of an SB3 step of the native vector env), else ``dict(zip(...))``."""
    if not all(isinstance(k, str) for k in keys):
        return lambda rows: [dict(zip(keys, row)) for row in rows]
    items = ", ".join(f"{k!r}: row[{i}]" for i, k in enumerate(keys))
    return eval(f"lambda rows: [{{{items}}} for row in rows]", {})  # the keys only as literals (repr of a str)


class NativeVecEnv(VecEnv):
    """``num_envs`` EHSSTracking-v0 envs as one SB3 VecEnv over the native vector env (module docstring).

    Args:
        num_envs: number of sub-envs (>= 1).
        env_kwargs: keyword arguments of ``EHSSTracking-v0`` (those of :class:`~ehss_gym.envs.env.EHSSTrackingEnv`).
    """

    def __init__(self, num_envs: int, env_kwargs: dict):
        self.venv = EHSSTrackingVectorEnv(num_envs, autoreset_mode=AutoresetMode.DISABLED, **env_kwargs)
        super().__init__(num_envs, self.venv.single_observation_space, self.venv.single_action_space)
        self._actions: np.ndarray | None = None
        self._returns = np.zeros(num_envs)  # [-] return of the running episode, summed in float64 as Monitor does
        self._lengths = np.zeros(num_envs, dtype=np.int64)  # [agent steps]
        self._t_start = time.time()

    # --- SB3's VecEnv: reset and step -----------------------------------------------------------------

    def _lane_options(self) -> dict | None:
        """The per-sub-env reset options (SB3's ``set_options``) as the vector env's options."""
        given = [o for o in self._options if o]
        if not given:
            return None
        bad = sorted({k for o in given for k in o} - {"scenario"})
        if bad:
            raise ValueError(f"reset options {bad} are not supported by NativeVecEnv; valid: ['scenario']")
        return {"scenario": [o.get("scenario", self.venv.config.scenario) for o in self._options]}

    def reset(self) -> np.ndarray:
        """Reset every sub-env (seeds and options set by ``seed`` / ``set_options`` apply once); observations."""
        obs, infos = self.venv.reset(seed=list(self._seeds), options=self._lane_options())
        self.reset_infos = lane_infos(infos, self.num_envs)
        self._reset_seeds()
        self._reset_options()
        self._returns[:] = 0.0
        self._lengths[:] = 0
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        """Queue the actions (num_envs, 1) of the next :meth:`step_wait`."""
        self._actions = actions

    def step_wait(self):
        """Advance every sub-env one agent step; ended episodes restart in the same step (module docstring).

        Returns:
            (observations (num_envs, D) float32, rewards (num_envs,) float32, dones (num_envs,) bool, infos: one
            dict per sub-env).
        """
        obs, rewards, terminated, truncated, stacked = self.venv.step(self._actions)
        self._returns += rewards
        self._lengths += 1
        dones = terminated | truncated
        infos = lane_infos(stacked, self.num_envs)
        ended = np.flatnonzero(dones)
        for i in ended:  # what the single env and Monitor add at the end of an episode, in their order
            if terminated[i]:
                infos[i]["t_diverged"] = infos[i]["metrics"]["t_diverged"]
            infos[i]["episode"] = {"r": round(float(self._returns[i]), 6), "l": int(self._lengths[i]),
                                   "t": round(time.time() - self._t_start, 6)}
        for i, info in enumerate(infos):  # then DummyVecEnv's
            info["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
        if len(ended):
            for i in ended:
                infos[i]["terminal_observation"] = obs[i].copy()
            obs, reset = self.venv.reset(options={"reset_mask": dones.copy()})
            for i, info in enumerate(lane_infos(reset, self.num_envs, ended)):
                if dones[i]:
                    self.reset_infos[i] = info
            self._returns[ended] = 0.0
            self._lengths[ended] = 0
        return obs, rewards.astype(np.float32), dones, infos

    def close(self) -> None:
        """Close the native vector env."""
        self.venv.close()

    # --- attributes and methods -------------------------------------------------------------------------

    def _lane_rng(self, i: int) -> np.random.Generator:
        """Sub-env i's scenario generator, made (unseeded) if it has none yet, as ``gym.Env.np_random`` does."""
        rngs = self.venv._rngs  # the lanes' generators; the vector env has no public accessor for them yet
        if rngs[i] is None:
            rngs[i], _ = seeding.np_random()
        return rngs[i]

    def _all(self, indices, what: str) -> list[int]:
        idx = list(self._get_indices(indices))
        if sorted(idx) != list(range(self.num_envs)):
            raise ValueError(f"{what} acts on the native vector env, which holds all {self.num_envs} sub-envs; "
                             f"indices {idx} name only some of them")
        return idx

    def get_attr(self, attr_name: str, indices=None) -> list:
        """``np_random``: each sub-env's generator; anything else: the native vector env's attribute, per index."""
        idx = list(self._get_indices(indices))
        if attr_name == "np_random":
            return [self._lane_rng(i) for i in idx]
        value = getattr(self.venv, attr_name)  # AttributeError if it has none (VecEnv.has_attr relies on it)
        return [value for _ in idx]

    def set_attr(self, attr_name: str, value, indices=None) -> None:
        """``np_random``: replace sub-envs' generators; anything else: set it on the native vector env (all)."""
        if attr_name == "np_random":
            for i in self._get_indices(indices):
                self.venv._rngs[i] = value  # see _lane_rng
            return
        self._all(indices, f"set_attr({attr_name!r})")
        setattr(self.venv, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list:
        """Call ``method_name`` once on the native vector env (all sub-envs); its result, per index."""
        idx = self._all(indices, f"env_method({method_name!r})")
        result = getattr(self.venv, method_name)(*method_args, **method_kwargs)
        return [result for _ in idx]

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices=None) -> list[bool]:
        """True for Monitor (and its bases): every sub-env reports episodes as Monitor does."""
        return [issubclass(Monitor, wrapper_class) for _ in self._get_indices(indices)]


__all__ = ["NativeVecEnv", "lane_infos"]
