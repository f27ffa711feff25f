"""Hyperparameter files for rl-zoo3 (``ppo.yml``); ``ehss_gym.agents.hyperparams.ppo`` exposes it as a module."""
