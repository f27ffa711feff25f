"""Hyperparameter files for rl-zoo3 (``ppo.yml``); ``ehss_gym.hyperparams.ppo`` exposes it as a module."""
