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
from stable_baselines3.common.distributions import DiagGaussianDistribution
from stable_baselines3.common.policies import ActorCriticPolicy

from ehss_gym.core.scenarios import DEFAULT_DISTRIBUTION
from ehss_gym.envs.config import EnvConfig

from .noise import ColoredNoise
from .specs import AgentSpec, LinearSchedule, ppo_kwargs, sac_kwargs

PINK_BETA = 1.0  # the "pink" exploration's spectrum exponent (Eberhard et al. 2023)


class ColoredGaussian(DiagGaussianDistribution):
    """SB3's diagonal Gaussian whose samples take their standard normals from a colored-noise process per sub-env
    (:class:`ehss_gym.agents.noise.ColoredNoise`): the same mean, std and log-probability (the marginal of every sample
    is the Gaussian), with samples correlated in time. One process per batch size (the rollouts' n_envs; a stochastic
    ``predict`` of another batch gets its own).

    Args:
        action_dim: the action's size.
        beta: the spectrum's exponent (1 = pink).
        seq_len: the noise sequences' length [agent steps] (an episode).
        seed: the seed of the noise's generator.
    """

    def __init__(self, action_dim: int, beta: float, seq_len: int, seed: int):
        super().__init__(action_dim)
        self.beta, self.seq_len = float(beta), int(seq_len)
        self.rng = np.random.default_rng(seed)
        self._noise: dict[int, ColoredNoise] = {}

    def sample(self) -> torch.Tensor:
        mean = self.distribution.mean
        n = mean.shape[0]
        if n not in self._noise:
            self._noise[n] = ColoredNoise(self.beta, n, self.action_dim, self.seq_len, self.rng)
        eps = torch.as_tensor(self._noise[n].sample(), dtype=mean.dtype)
        return mean + self.distribution.stddev * eps

ACTIVATIONS = {"tanh": torch.nn.Tanh, "relu": torch.nn.ReLU}
POLICY_PATH = "ehss_gym.agents.factory.AgentMlpPolicy"  # how rl-zoo3 names the class (``policy:`` in ppo.yml)


class AgentMlpPolicy(ActorCriticPolicy):
    """SB3's ``MlpPolicy`` (an MLP actor-critic) whose action net can start at zero.

    With ``zero_init_action=True`` the action net's weight and bias are zeroed after SB3's (orthogonal)
    initialisation, so the Gaussian mean is exactly 0 for every observation: a residual agent starts as its base
    law. Zeroing draws no random numbers, so every other parameter is the one ``MlpPolicy`` gets from the same
    seed. The hidden layers still learn: the gradient of the action-net weight is the (non-zero) hidden activation
    times the advantage-weighted score, so after the first update the mean moves.

    With ``noise_beta`` the rollouts' samples take colored noise (:class:`ColoredGaussian`; 1 = pink) instead of
    white; the noise's generator is seeded from torch's after the networks are made (so they are the ones the same
    seed gives without it). With gSDE (``use_sde=True``) the action net is the mean's, zeroed alike.

    Args:
        *args: as :class:`stable_baselines3.common.policies.ActorCriticPolicy`.
        zero_init_action: zero the action net at construction.
        noise_beta: the exponent of the rollouts' colored noise (None: white, SB3's).
        noise_seq_len: its sequences' length [agent steps].
        **kwargs: as :class:`stable_baselines3.common.policies.ActorCriticPolicy`.
    """

    def __init__(self, *args, zero_init_action: bool = False, noise_beta: float | None = None,
                 noise_seq_len: int = 2000, **kwargs):
        self.zero_init_action = bool(zero_init_action)
        self.noise_beta = None if noise_beta is None else float(noise_beta)
        self.noise_seq_len = int(noise_seq_len)
        super().__init__(*args, **kwargs)

    def _build(self, lr_schedule) -> None:
        super()._build(lr_schedule)
        if self.zero_init_action:
            zero_action_net(self)
        if self.noise_beta is not None:
            seed = int(torch.randint(0, 2**62, (1,)).item())
            self.action_dist = ColoredGaussian(int(np.prod(self.action_space.shape)), self.noise_beta,
                                               self.noise_seq_len, seed)

    def _get_constructor_parameters(self) -> dict:
        return {**super()._get_constructor_parameters(), "zero_init_action": self.zero_init_action,
                "noise_beta": self.noise_beta, "noise_seq_len": self.noise_seq_len}


def zero_action_net(policy) -> None:
    """Zero the action net's weight and bias of ``policy`` (an SB3 model or its policy): a mean of exactly 0."""
    net = getattr(policy, "policy", policy).action_net
    with torch.no_grad():
        net.weight.zero_()
        net.bias.zero_()


def episode_steps(spec: AgentSpec) -> int:
    """Agent steps of a training episode of ``spec``'s env (the colored noise's sequence length)."""
    cfg = EnvConfig.from_kwargs(spec.env_kwargs)
    return max(2, round((cfg.episode_seconds or DEFAULT_DISTRIBUTION.episode_seconds) / cfg.agent_dt))


def sde_log_std_init(spec: AgentSpec) -> float:
    """gSDE's initial log std of its noise matrix: the spec's, less ln(sqrt(last hidden size)), so that hidden features
    of unit size (|features| = sqrt(size)) give the spec's std."""
    return spec.log_std_init - 0.5 * math.log(spec.net_arch[-1])


def policy_kwargs(spec: AgentSpec) -> dict:
    """``policy_kwargs`` of :class:`AgentMlpPolicy` for ``spec``: hidden sizes, activation, initial log std and the
    exploration noise (gSDE's matrix scale, the pink noise)."""
    if spec.activation not in ACTIVATIONS:
        raise ValueError(f"activation must be one of {sorted(ACTIVATIONS)}, got {spec.activation!r}")
    out = {"net_arch": {"pi": list(spec.net_arch), "vf": list(spec.net_arch)},
           "activation_fn": ACTIVATIONS[spec.activation], "log_std_init": spec.log_std_init,
           "zero_init_action": spec.zero_init_action}
    if spec.exploration == "gsde":
        out["log_std_init"] = sde_log_std_init(spec)
    if spec.exploration == "pink":
        out.update(noise_beta=PINK_BETA, noise_seq_len=episode_steps(spec))
    return out


def exploration_kwargs(spec: AgentSpec) -> dict:
    """SB3 PPO's own keyword arguments of the exploration (gSDE's)."""
    return {"use_sde": True, "sde_sample_freq": spec.sde_sample_freq} if spec.exploration == "gsde" else {}


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
               **exploration_kwargs(spec), policy_kwargs=policy_kwargs(spec), tensorboard_log=tensorboard_log,
               seed=seed, device="cpu", verbose=verbose)


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


__all__ = ["ACTIVATIONS", "POLICY_PATH", "PINK_BETA", "ColoredGaussian", "AgentMlpPolicy", "zero_action_net",
           "episode_steps", "sde_log_std_init", "policy_kwargs", "exploration_kwargs", "learning_rate", "make_agent",
           "make_sac", "initial_mean_abs"]
