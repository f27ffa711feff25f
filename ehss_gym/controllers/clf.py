"""The Sontag/CLF law as a fixed policy (a zero residual, or the law's own current in direct mode)."""

from __future__ import annotations

import numpy as np

from .base import ScriptedPolicy


class CLFPolicy(ScriptedPolicy):
    """The Sontag/CLF law (for the env's n): zero residual, or the Sontag current in direct mode."""

    def act(self, obs, state, episode_start):
        if self.config.mode == "residual":
            return np.zeros((obs.shape[0], 1)), state
        u = self.value(obs, "u_base")
        return (u / self.config.residual_scale).reshape(-1, 1), state
