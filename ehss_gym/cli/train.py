"""``ehss train``: train residual PPO, pure PPO or residual SAC on EHSSTracking-v0 (one seed, or several in parallel).

    ehss train --agent {residual-ppo,ppo,residual-sac} --task velocity --n 2 --timesteps T --seed S
        [--out runs/NAME] [--resume]
    ehss train --seeds 0-4 [--workers W] [...]   # one process per usable core; runs go to <out or runs>/<run name>

The options are the fields of :class:`ehss_gym.train.config.Config` and :class:`~ehss_gym.train.config.Launch`;
the runner is :mod:`ehss_gym.train.launch`, the training script :mod:`ehss_gym.train.loop`. Bad input (an
unknown agent, a bad --seeds range, --resume without a checkpoint, ...) prints a message naming the option and
exits with 2.
"""

from __future__ import annotations

from ehss_gym.train import launch


def run(args) -> int:
    """Run ``ehss train`` with parsed arguments (:func:`ehss_gym.train.launch.run_from_args`)."""
    return launch.run_from_args(args, prog="ehss train")


__all__ = ["run"]
