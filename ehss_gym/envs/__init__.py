"""``EHSSTracking-v0``: the single env, the native vector env, their configuration and the one rollout loop.

Importing this package (or ``ehss_gym``) registers ``EHSSTracking-v0`` with Gymnasium. Gymnasium 1.x loads no
plugin entry points, so in a fresh interpreter use its ``"module:EnvId"`` form,
``gymnasium.make("ehss_gym:EHSSTracking-v0")``, which imports ``ehss_gym`` first.
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
    """Register ``EHSSTracking-v0`` and its vector entry point with Gymnasium (idempotent; run on import)."""
    if ENV_ID not in gym.registry:
        gym.register(ENV_ID, entry_point="ehss_gym.envs.env:EHSSTrackingEnv",
                     vector_entry_point="ehss_gym.envs.vector:EHSSTrackingVectorEnv")


register_envs()

__all__ = ["ENV_ID", "DEFAULTS", "EnvConfig", "EnvDefaults", "TaskDefaults", "EHSSTrackingEnv", "EHSSTrackingVectorEnv",
           "OBS_BOUND", "decode_observation", "observation_layout", "symlog_inverse", "rollout", "EpisodeResult",
           "register_envs"]
