"""The scripted policies' common base: SB3's ``predict`` on one observation or a batch, decoded to physical values."""

from __future__ import annotations

import numpy as np

from ehss_gym.envs import EnvConfig, decode_observation, observation_layout


def _config_of(env) -> EnvConfig:
    """The EnvConfig of an env, a wrapped env, a vector env, an SB3 VecEnv, or an EnvConfig itself."""
    if isinstance(env, EnvConfig):
        return env
    for getter in (lambda e: e.unwrapped.config, lambda e: e.config, lambda e: e.get_attr("config")[0],
                   lambda e: e.envs[0].unwrapped.config):
        try:
            cfg = getter(env)
        except Exception:  # noqa: BLE001 - try the next way to reach the config
            continue
        if isinstance(cfg, EnvConfig):
            return cfg
    raise ValueError(f"cannot find an EHSSTracking-v0 config in {env!r}; pass the env (or its EnvConfig)")


class ScriptedPolicy:
    """Base class: SB3-style ``predict`` on top of :meth:`act` (batch of observations -> actions)."""

    @staticmethod
    def _fresh_state(obs, state, episode_start):
        """One float of memory per env, zeroed where an episode starts."""
        n = obs.shape[0]
        if state is None or np.shape(state) != (n, 1):
            state = np.zeros((n, 1))
        else:
            state = np.array(state, dtype=np.float64)
        state[episode_start] = 0.0
        return state

    def __init__(self, env):
        self.config = _config_of(env)
        self.layout = observation_layout(self.config)
        self._index = {row[0]: (i, row[2], row[3]) for i, row in enumerate(self.layout)}

    def act(self, obs: np.ndarray, state, episode_start: np.ndarray):
        """Actions (n, 1) for observations (n, D); returns (actions, state)."""
        raise NotImplementedError

    # False for a policy whose actions do not depend on what it observes (it then has a fixed action)
    observes = True

    def fixed_action(self, n: int) -> np.ndarray | None:
        """The actions (n, 1) this policy takes in n envs whatever they observe (:meth:`predict` on any observations;
        :func:`ehss_gym.envs.rollouts.rollout` then holds them over many steps per compiled call), or None if they
        depend on what it observes."""
        if self.observes:
            return None
        return self.predict(np.zeros((n, len(self.layout)), dtype=np.float32))[0]

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        """SB3 interface: actions with the observation's batch shape, and the next state."""
        obs = np.asarray(observation, dtype=np.float32)
        single = obs.ndim == 1
        obs2 = obs.reshape(1, -1) if single else obs
        n = obs2.shape[0]
        if episode_start is None:
            starts = np.zeros(n, dtype=bool) if state is not None else np.ones(n, dtype=bool)
        else:
            starts = np.asarray(episode_start, dtype=bool).reshape(-1)
            if starts.size == 1 and n > 1:
                starts = np.repeat(starts, n)
        actions, state = self.act(obs2, state, starts)
        actions = np.clip(np.asarray(actions, dtype=np.float32).reshape(n, 1), -1.0, 1.0)
        return (actions[0] if single else actions), state

    def decode(self, obs: np.ndarray) -> dict:
        """All physical values of observations (n, D); see :func:`ehss_gym.envs.observation.decode_observation`."""
        return decode_observation(obs, self.layout)

    def value(self, obs: np.ndarray, name: str) -> np.ndarray:
        """One physical value (n,) of observations (n, D), e.g. "e" or "u_base"."""
        i, scale, squash = self._index[name]
        v = obs[:, i].astype(np.float64)
        return (np.sign(v) * np.expm1(np.abs(v)) if squash else v) * scale
