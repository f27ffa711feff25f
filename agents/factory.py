"""The SB3 model of an agent spec: PPO with the policy class :class:`AgentMlpPolicy`, or SAC (the comparison
algorithm) with SB3's MlpPolicy (torch at import).

Only training imports this module (``ehss train``, rl-zoo3 through the generated ``agents/hyperparams``, the
benchmarks); loading a shipped policy needs :mod:`ehss_gym.agents.safeweights` alone.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from stable_baselines3 import PPO, SAC
from stable_baselines3.common.policies import ActorCriticPolicy

from .specs import AgentSpec, LinearSchedule, ppo_kwargs, sac_kwargs

ACTIVATIONS = {"tanh": torch.nn.Tanh, "relu": torch.nn.ReLU}
POLICY_PATH = "ehss_gym.agents.factory.AgentMlpPolicy"  # how rl-zoo3 names the class (``policy:`` in ppo.yml)


class AgentMlpPolicy(ActorCriticPolicy):
    """SB3's ``MlpPolicy`` (an MLP actor-critic) whose action net can start at zero.

    With ``zero_init_action=True`` the action net's weight and bias are zeroed after SB3's (orthogonal)
    initialisation, so the Gaussian mean is exactly 0 for every observation: a residual agent starts as its base
    law. Zeroing draws no random numbers, so every other parameter is the one ``MlpPolicy`` gets from the same
    seed. The hidden layers still learn: the gradient of the action-net weight is the (non-zero) hidden activation
    times the advantage-weighted score, so after the first update the mean moves.

    Args:
        *args: as :class:`stable_baselines3.common.policies.ActorCriticPolicy`.
        zero_init_action: zero the action net at construction.
        **kwargs: as :class:`stable_baselines3.common.policies.ActorCriticPolicy`.
    """

    def __init__(self, *args, zero_init_action: bool = False, **kwargs):
        self.zero_init_action = bool(zero_init_action)
        super().__init__(*args, **kwargs)

    def _build(self, lr_schedule) -> None:
        super()._build(lr_schedule)
        if self.zero_init_action:
            zero_action_net(self)

    def _get_constructor_parameters(self) -> dict:
        return {**super()._get_constructor_parameters(), "zero_init_action": self.zero_init_action}


def zero_action_net(policy) -> None:
    """Zero the action net's weight and bias of ``policy`` (an SB3 model or its policy): a mean of exactly 0."""
    net = getattr(policy, "policy", policy).action_net
    with torch.no_grad():
        net.weight.zero_()
        net.bias.zero_()


def policy_kwargs(spec: AgentSpec) -> dict:
    """``policy_kwargs`` of :class:`AgentMlpPolicy` for ``spec``: hidden sizes, activation, initial log std."""
    if spec.activation not in ACTIVATIONS:
        raise ValueError(f"activation must be one of {sorted(ACTIVATIONS)}, got {spec.activation!r}")
    return {"net_arch": {"pi": list(spec.net_arch), "vf": list(spec.net_arch)},
            "activation_fn": ACTIVATIONS[spec.activation], "log_std_init": spec.log_std_init,
            "zero_init_action": spec.zero_init_action}


def learning_rate(spec: AgentSpec):
    """The learning rate of ``spec``: a float, or a :class:`~ehss_gym.agents.specs.LinearSchedule` to 0."""
    return spec.learning_rate if spec.lr_schedule == "constant" else LinearSchedule(spec.learning_rate)


def make_agent(spec: AgentSpec, venv, seed: int, tensorboard_log: str | None = None, verbose: int = 0):
    """Build the SB3 model of ``spec`` (PPO, or SAC: :func:`make_sac`) on the (VecNormalize-wrapped) vector env.

    Args:
        spec: the agent's hyperparameters.
        venv: an SB3 VecEnv of ``EHSSTracking-v0`` in ``spec.mode``.
        seed: seeds SB3 (torch, NumPy, Python, the env's scenario draws and the action space).
        tensorboard_log: TensorBoard folder or None.
        verbose: SB3 verbosity.
    """
    if spec.algo == "sac":
        return make_sac(spec, venv, seed, tensorboard_log, verbose)
    return PPO(AgentMlpPolicy, venv, learning_rate=learning_rate(spec), **ppo_kwargs(spec),
               policy_kwargs=policy_kwargs(spec), tensorboard_log=tensorboard_log, seed=seed, device="cpu",
               verbose=verbose)


def make_sac(spec: AgentSpec, venv, seed: int, tensorboard_log: str | None = None, verbose: int = 0) -> SAC:
    """SB3's SAC for ``spec``: MlpPolicy with the spec's hidden sizes and activation; with ``zero_init_action`` the
    actor's mean layer zeroed (a squashed mean of exactly 0: the base law) and its state-dependent log-std layer set
    to the constant ``log_std_init``; the entropy temperature tuned to the initial Gaussian's entropy per action
    dimension, log_std_init + log(2 pi e)/2 (so the auto-tuning holds the initial exploration rather than widening
    it to SB3's default target)."""
    if spec.activation not in ACTIVATIONS:
        raise ValueError(f"activation must be one of {sorted(ACTIVATIONS)}, got {spec.activation!r}")
    act_dim = int(np.prod(venv.action_space.shape))
    model = SAC("MlpPolicy", venv, learning_rate=learning_rate(spec), **sac_kwargs(spec), ent_coef="auto",
                target_entropy=act_dim * (spec.log_std_init + 0.5 * math.log(2.0 * math.pi * math.e)),
                policy_kwargs={"net_arch": list(spec.net_arch), "activation_fn": ACTIVATIONS[spec.activation]},
                tensorboard_log=tensorboard_log, seed=seed, device="cpu", verbose=verbose)
    if spec.zero_init_action:
        with torch.no_grad():
            actor = model.policy.actor
            actor.mu.weight.zero_()
            actor.mu.bias.zero_()
            actor.log_std.weight.zero_()
            actor.log_std.bias.fill_(spec.log_std_init)
    return model


def initial_mean_abs(model, obs: np.ndarray) -> float:
    """max |mean action| of ``model`` over a batch of (normalised) observations (B, D) [action units]."""
    with torch.no_grad():
        dist = model.policy.get_distribution(torch.as_tensor(obs).float())
        return float(dist.distribution.mean.abs().max())


__all__ = ["ACTIVATIONS", "POLICY_PATH", "AgentMlpPolicy", "zero_action_net", "policy_kwargs", "learning_rate",
           "make_agent", "make_sac", "initial_mean_abs"]
