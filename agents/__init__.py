"""Learned agents for EHSSTracking-v0: residual PPO on the Sontag/CLF law and pure PPO (the baseline).

This folder is the package ``ehss_gym.agents`` (pyproject.toml maps it, so ``ehss train`` works from a
wheel); import it under that name (``import agents`` from the repository root fails, see
:mod:`ehss_gym.agents._checkout`). Modules:

- :mod:`~ehss_gym.agents.specs`: :class:`AgentSpec` and :data:`AGENTS`, every hyperparameter with its reason
  (plain data, no torch);
- :mod:`~ehss_gym.agents.factory`: the SB3 PPO model of a spec (torch; only training imports it);
- :mod:`~ehss_gym.agents.safeweights`: load a shipped policy without unpickling and without torch;
- :mod:`~ehss_gym.agents.export`: write a trained SB3 policy as safe weights (torch);
- ``hyperparams/ppo.yml`` and ``ppo.py``: rl-zoo3's configuration, generated from :data:`AGENTS`
  (``python -m ehss_gym.train.zoo``).

    from ehss_gym.agents import AGENTS, get_spec
    spec = get_spec("residual-ppo")           # or get_spec("residual-ppo", gamma=0.99)
"""

from . import _checkout  # noqa: F401  (first: refuses a top-level "import agents" of a checkout)
from .specs import AGENTS, AgentSpec, agent_names, env_kwargs_for, get_spec

__all__ = ["AGENTS", "AgentSpec", "agent_names", "env_kwargs_for", "get_spec"]
