"""Training entry point. The script itself is :mod:`ehss_gym.train.loop` (read it top to bottom); it lives in
the package so that ``ehss train`` works from an installed wheel. From a checkout::

    python -m train.ppo --agent residual-ppo --task velocity --n 2 --timesteps 300000 --seed 0
    ehss train --agent residual-ppo --seeds 0-4          # the same through the CLI, one process per core
"""

from .loop import Config, make_env, train

__all__ = ["Config", "make_env", "train"]
