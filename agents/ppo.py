"""Pure PPO: the whole valve current comes from the policy (env mode "direct"); the baseline that shows
what the base law contributes. Hyperparameters: :data:`ehss_gym.rl.agents.AGENTS` ``["ppo"]``.
"""

from ehss_gym.rl.agents import get_spec, make_agent

SPEC = get_spec("ppo")


def make(venv, seed: int = 0, tensorboard_log: str | None = None, **overrides):
    """The pure-PPO model on ``venv`` (an SB3 VecEnv of EHSSTracking-v0, mode "direct")."""
    return make_agent(get_spec("ppo", **overrides), venv, seed, tensorboard_log)
