"""Learned agents for EHSSTracking-v0: residual PPO on the Sontag/CLF law and pure PPO (the baseline).

A thin entry point for readers of the repository: the implementation lives in :mod:`ehss_gym.agents.specs`
(inside the installed package, so ``ehss train`` works from a wheel without installing generic top-level
``agents``/``train`` packages into site-packages). Every hyperparameter is documented there, in
:class:`AgentSpec` and :data:`AGENTS`.

    from agents import AGENTS, get_spec, make_agent
    spec = get_spec("residual-ppo")           # or get_spec("residual-ppo", gamma=0.99)
"""

from .specs import AGENTS, AgentSpec, agent_names, env_kwargs_for, get_spec, make_agent, zero_action_net

__all__ = ["AGENTS", "AgentSpec", "agent_names", "env_kwargs_for", "get_spec", "make_agent", "zero_action_net"]
