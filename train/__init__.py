"""Training of the learned agents on EHSSTracking-v0 (this folder is the package ``ehss_gym.train``).

- :mod:`~ehss_gym.train.config`: :class:`Config`, the settings of a run (the flags are its fields) and
  :class:`Launch` (several seeds);
- :mod:`~ehss_gym.train.loop`: the training script, read top to bottom (``python -m ehss_gym.train.loop``);
- :mod:`~ehss_gym.train.vec_env`: the native vector env as an SB3 VecEnv (training steps all envs in one call);
- :mod:`~ehss_gym.train.callbacks`, :mod:`~ehss_gym.train.runs`: SB3 callbacks; run names, checkpoints, resume;
- :mod:`~ehss_gym.train.launch`: ``ehss train``, one process per seed;
- :mod:`~ehss_gym.train.options`: command-line options from a dataclass;
- :mod:`~ehss_gym.train.zoo`: writes rl-zoo3's ``agents/hyperparams`` from the agent specs.

The studies of the trained agents are in :mod:`ehss_gym.study`: :mod:`~ehss_gym.study.training` (behind ``ehss
training-report``) and :mod:`~ehss_gym.study.exploration` (the initial exploration noise).

From a checkout::

    ehss train --agent residual-ppo --task velocity --n 2 --timesteps 300000 --seed 0
    ehss train --agent residual-ppo --seeds 0-4          # one process per core

``import train`` from the repository root fails (see :mod:`ehss_gym.agents._checkout`): the package is
``ehss_gym.train``.
"""

from ehss_gym.agents._checkout import refuse_second_copy

refuse_second_copy(__name__, "ehss_gym.train")
