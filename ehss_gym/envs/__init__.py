"""``EHSSTracking-v0``: the single env, the native vector env, their configuration and the one rollout loop.

Importing this package registers ``EHSSTracking-v0`` with Gymnasium (``gymnasium.make`` also finds it
through the ``gymnasium.envs`` plugin entry point, without importing ehss_gym first).
"""

from __future__ import annotations

import gymnasium as gym

from .config import DEFAULTS, EnvConfig, EnvDefaults, TaskDefaults
from .env import EHSSTrackingEnv
from .observation import OBS_BOUND, decode_observation, observation_layout, symlog_inverse
from .rollout import EpisodeResult, rollout
from .vector import EHSSTrackingVectorEnv

ENV_ID = "EHSSTracking-v0"


def register_envs() -> None:
    """Register ``EHSSTracking-v0`` (idempotent); the ``gymnasium.envs`` entry point of the package."""
    if ENV_ID not in gym.registry:
        gym.register(ENV_ID, entry_point="ehss_gym.envs.env:EHSSTrackingEnv",
                     vector_entry_point="ehss_gym.envs.vector:EHSSTrackingVectorEnv")


register_envs()

__all__ = ["ENV_ID", "DEFAULTS", "EnvConfig", "EnvDefaults", "TaskDefaults", "EHSSTrackingEnv", "EHSSTrackingVectorEnv",
           "OBS_BOUND", "decode_observation", "observation_layout", "symlog_inverse", "rollout", "EpisodeResult",
           "register_envs"]
