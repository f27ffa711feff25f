"""Residual PPO: PPO whose action is a correction added to the Sontag/CLF current (env mode "residual").

The policy's mean starts at exactly zero (zero-initialised action net), so the untrained policy is the base
law; see :data:`ehss_gym.rl.agents.AGENTS` ``["residual-ppo"]`` for every hyperparameter and its reason.
"""

from ehss_gym.rl.agents import get_spec, make_agent

SPEC = get_spec("residual-ppo")


def make(venv, seed: int = 0, tensorboard_log: str | None = None, **overrides):
    """The residual-PPO model on ``venv`` (an SB3 VecEnv of EHSSTracking-v0, mode "residual")."""
    return make_agent(get_spec("residual-ppo", **overrides), venv, seed, tensorboard_log)
