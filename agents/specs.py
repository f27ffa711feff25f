"""The two learned agents: residual PPO on top of the Sontag/CLF law, and pure PPO as the baseline.

Both are stable-baselines3 PPO with an MLP actor-critic on ``EHSSTracking-v0``; they differ in the env
mode and in how the policy starts.

- ``residual-ppo`` (env ``mode="residual"``): the action is a correction, ``residual_scale`` mA per
  unit, added to the Sontag current. The last layer of the action net is zero-initialised, so the
  Gaussian mean is exactly 0 and the deterministic policy *is* the base law at step 0. The initial
  exploration noise (``log_std_init``) is small: the stochastic rollouts stay close to the base law, and
  the first updates move the mean only a little (the measurement behind the value is in
  ``reports/training/TRAINING.md``, section "initial exploration noise").
- ``ppo`` (env ``mode="direct"``): pure RL, the action is the whole valve current, ``current_limit``
  mA per unit; standard initialisation (orthogonal, gain 0.01 on the action net) and a larger noise.

Every hyperparameter is in :data:`AGENTS` with the reason for its value. This module is plain data (no torch
at import): :mod:`ehss_gym.agents.factory` builds the SB3 model of a spec, and the rl-zoo3 files in
``agents/hyperparams/`` are generated from :data:`AGENTS` (:mod:`ehss_gym.train.zoo`). Observations are normalised
by ``VecNormalize`` (see :mod:`ehss_gym.train.loop`), rewards too.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

from ehss_gym.core.settings import TASKS
from ehss_gym.envs.config import POLICY_KEYS, EnvConfig
from ehss_gym.envs.law_table import COMPENSATOR_ROWS, compensator_settings

TASK_NAMES = tuple(TASKS)


@dataclass(frozen=True)
class AgentSpec:
    """Hyperparameters of one learned agent (PPO, Schulman et al. 2017; names as in stable-baselines3).

    Attributes:
        name: agent name used on the command line.
        mode: env mode, "residual" or "direct".
        env_kwargs: extra ``gym.make("EHSSTracking-v0", ...)`` keyword arguments (on top of task and n).
        n_envs: parallel envs per run; rollout size is n_envs * n_steps agent steps.
        n_steps: agent steps per env per rollout.
        batch_size: minibatch size of the PPO update.
        n_epochs: passes over each rollout.
        learning_rate: Adam step size (initial value with ``lr_schedule="linear"``).
        lr_schedule: "constant", or "linear" (annealed to 0 over the run, as in CleanRL's anneal_lr: the last
            updates are small, so the final policy does not oscillate between evaluations).
        gamma: discount per agent step (an agent step is agent_period * control_period: 1 ms for both agents).
        gae_lambda: GAE lambda.
        clip_range: PPO ratio clip.
        ent_coef: entropy bonus.
        vf_coef: value-loss weight.
        max_grad_norm: gradient-norm clip.
        target_kl: early stop of an update's epochs when the approximate KL exceeds it (None = off).
        net_arch: hidden sizes of the actor (pi) and critic (vf).
        activation: hidden activation ("tanh" or "relu").
        log_std_init: initial log standard deviation of the Gaussian action noise (action units).
        zero_init_action: zero the action net's weights and bias, so the initial mean action is exactly 0.
        norm_reward: normalise rewards by VecNormalize's running return std.
        algo: the algorithm, "ppo" (the agents' own) or "sac" (soft actor-critic, Haarnoja et al. 2018: the comparison
            algorithm; of the fields above it reads n_envs, batch_size, learning_rate, lr_schedule, gamma, net_arch,
            activation, log_std_init, zero_init_action and norm_reward, and the next five).
        buffer_size: SAC's replay buffer [transitions].
        learning_starts: SAC's steps of the initial policy before the first update.
        train_freq: SAC's env steps (per env) between updates.
        gradient_steps: SAC's gradient steps per update.
        tau: SAC's target-network averaging rate.
        exploration: how PPO's rollouts sample the Gaussian: "gaussian" (white noise, SB3's), "gsde" (SB3's
            generalised state-dependent exploration, Raffin et al. 2022: noise = the policy's last hidden features
            times a Gaussian matrix redrawn every ``sde_sample_freq`` steps, smooth wherever the features are; its
            matrix starts at log_std_init - ln(sqrt(hidden size)), so features of unit size give the spec's std) or
            "pink" (the Gaussian's standard normals from a pink-noise sequence per sub-env, beta 1, one episode long:
            Eberhard et al. 2023, :mod:`ehss_gym.agents.noise`). The deterministic policy is the same MLP in all
            three (exported alike).
        sde_sample_freq: gSDE's steps between redraws of its noise matrix (-1: once per rollout).
        tasks: the tasks the agent trains on (an agent whose base law was chosen for one task names only it).
    """

    name: str
    mode: str
    env_kwargs: dict = field(default_factory=dict)
    n_envs: int = 8
    n_steps: int = 256
    batch_size: int = 256
    n_epochs: int = 5
    learning_rate: float = 3e-4
    lr_schedule: str = "linear"
    gamma: float = 0.98
    gae_lambda: float = 0.95
    clip_range: float = 0.2
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    target_kl: float | None = 0.03
    net_arch: tuple = (64, 64)
    activation: str = "tanh"
    log_std_init: float = -2.0
    zero_init_action: bool = False
    norm_reward: bool = True
    algo: str = "ppo"
    buffer_size: int = 200_000
    learning_starts: int = 2_000
    train_freq: int = 8
    gradient_steps: int = 8
    tau: float = 0.005
    exploration: str = "gaussian"
    sde_sample_freq: int = 16
    tasks: tuple = TASK_NAMES

    def __post_init__(self):
        def bad(name, what):
            raise ValueError(f"{name} must be {what}, got {getattr(self, name)!r}")

        for name in ("n_envs", "n_steps", "batch_size", "n_epochs", "buffer_size", "train_freq", "gradient_steps"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                bad(name, "an integer >= 1")
        for name, lo, hi in (("learning_rate", 0.0, math.inf), ("gamma", 0.0, 1.0), ("gae_lambda", 0.0, 1.0),
                             ("clip_range", 0.0, math.inf), ("max_grad_norm", 0.0, math.inf)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not lo < v <= hi:
                bad(name, f"a number in ({lo:g}, {hi:g}]")
        for name in ("ent_coef", "vf_coef"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0.0 <= v < math.inf:
                bad(name, "a finite number >= 0")
        if self.target_kl is not None and (isinstance(self.target_kl, bool) or not isinstance(self.target_kl, (
                int, float)) or not 0.0 < self.target_kl < math.inf):
            bad("target_kl", "null or a finite number > 0")
        if not self.net_arch or not all(isinstance(h, int) and not isinstance(h, bool) and h >= 1
                                        for h in self.net_arch):
            bad("net_arch", "a non-empty list of integers >= 1")
        if self.lr_schedule not in ("constant", "linear"):
            bad("lr_schedule", "'constant' or 'linear'")
        if self.activation not in ("tanh", "relu"):
            bad("activation", "'tanh' or 'relu'")
        if isinstance(self.log_std_init, bool) or not isinstance(self.log_std_init, (int, float)) \
                or not math.isfinite(self.log_std_init):
            bad("log_std_init", "a finite number")
        if self.mode not in ("residual", "direct"):
            bad("mode", "'residual' or 'direct'")
        if self.algo not in ALGOS:
            bad("algo", f"one of {list(ALGOS)}")
        if self.exploration not in EXPLORATIONS or (self.algo != "ppo" and self.exploration != "gaussian"):
            bad("exploration", f"one of {list(EXPLORATIONS)} (PPO; SAC: 'gaussian')")
        sf = self.sde_sample_freq
        if isinstance(sf, bool) or not isinstance(sf, int) or not (sf == -1 or sf >= 1):
            bad("sde_sample_freq", "-1 or an integer >= 1")
        ls = self.learning_starts
        if isinstance(ls, bool) or not isinstance(ls, int) or ls < 0:
            bad("learning_starts", "an integer >= 0")
        if isinstance(self.tau, bool) or not isinstance(self.tau, (int, float)) or not 0.0 < self.tau <= 1.0:
            bad("tau", "a number in (0, 1]")
        if isinstance(self.tasks, list):  # (as a run's record holds it)
            object.__setattr__(self, "tasks", tuple(self.tasks))
        if not isinstance(self.tasks, tuple) or not self.tasks or not set(self.tasks) <= set(TASK_NAMES):
            bad("tasks", f"a non-empty tuple of tasks of {list(TASK_NAMES)}")
        if not isinstance(self.env_kwargs, dict) or {"task", "n", "mode"} & set(self.env_kwargs):
            bad("env_kwargs", "a dict of EHSSTracking-v0 keyword arguments other than task, n and mode")

    def as_dict(self) -> dict:
        """The spec as JSON values (``net_arch`` a list): what a run's ``config.json`` records. A PPO spec leaves out
        ``algo`` and SAC's fields (so a PPO run's record, and its run name, are what they were before them)."""
        d = asdict(self)
        d["net_arch"] = list(self.net_arch)
        if self.algo == "ppo":
            for k in ("algo", *SAC_KEYS):
                d.pop(k)
        if self.exploration == "gaussian":  # (the record of a run with SB3's white noise as before the option)
            for k in EXPLORATION_KEYS:
                d.pop(k)
        if self.tasks == TASK_NAMES:  # (an agent of both tasks keeps the record it had before the field)
            d.pop("tasks")
        else:
            d["tasks"] = list(self.tasks)
        return d


# What the agents' env sets beyond the env's defaults. None of it is a setting of the law or the loop: the agents train
# in the loop the env's defaults make when a run starts (the tuned law with its boundary layer, the estimator, the
# shaper, the bumpless start), the loop every scripted policy is scored in. An exported policy records every setting
# it acts in (PINNED_ENV_KEYS), so the shipped models, trained with the first recipe (which pinned h = 50 us and the
# plain law, smoothing 0, in an earlier loop; their JSON files), still act in the loop they were trained in.
# - act every 20 control periods (1 ms): the agent's rate, not the law's. Kept from the first recipe, where pilot runs
#   (one seed, 300k steps, 16 validation episodes; reports/training/TRAINING.md) with a rate weight lowered the
#   residual's added TV fastest at this rate; not re-measured with the class reward. At the env's default of 5 every
#   simulated second costs 4x the policy evaluations.
COMMON_ENV = {"agent_period": 20}
# The residual agent's problem, reward, action and memory: the winner of the recipe's ablation (``ehss ablation``,
# reports/training/ablation: reward x action x exploration x base x training distribution, position, n = 2, seed 0,
# 300k steps per cell, judged by a rule written before the runs), physical-schedule-gaussian-law:
# - unmodelled_effects: every training episode draws the valve's threshold and hysteresis, the sensors' delay and
#   quantisation and their noise (docs/ENV.md): where the law's model is wrong the errors are physical, and that is
#   what a residual can learn. (Half the episodes with the effects, the ablation's stage 3 on this cell: U 0.991,
#   H 1.020, against 0.957 and 1.039 with all of them; both admissible, and the rule ranks U first.)
# - action "schedule": the agent scales the law's boundary-layer width, sigma and observer bandwidth within stated
#   ranges at its rate (docs/ENV.md, "Actions"), the gain-scheduling route. It was the only cell of stages 1-2 whose
#   final policy was admissible (held-out figure H 1.039 <= 1.05), and it ends below its step-0 policy on the
#   unmodelled set (U 0.957). The current residual reached lower U (final 0.777-0.891) and the reference-shifting
#   actions 0.921-1.031, but both lost on the held-out episodes (H 1.92-2.35 and 1.28-1.78). On 5 seeds the winner's
#   best validation figure fell below step 0 in 5 of 5.
# - the physical per-step reward (weight 1; docs/RL.md, "Physical reward"): the episode's sum ranks fixed policies as
#   the ruler does, on the ruler's physical floors, with no dependence on the history (the class reward's step pays a
#   change of a running log ratio). Saturation weight 1 (the ruler's gate fails a mean saturation share above 10 %),
#   divergence 10 (the gate fails a diverged episode).
# - memory_tau 0.1 s: the filtered error integral and the action before last, so that a friction step (0.3-2 s in
#   the training distribution) is visible; a recurrent policy or a frame stack would cost more per step.
# - residual_scale 10 mA (the current limit) is the current residual's unit: kept so the recipe's record is that of
#   the ablation's cells; the schedule action does not read it.
RESIDUAL_ENV = {**COMMON_ENV, "residual_scale": 10.0, "memory_tau": 0.1, "unmodelled_effects": True,
                "action": "schedule",
                "reward_weights": {"track": 0.0, "effort": 0.0, "rate": 0.0, "physical": 1.0, "saturation": 1.0,
                                   "divergence": 10.0}}
# Settings pinned when a policy is exported (its JSON records them all), so that later changes of the env's
# defaults cannot silently change the loop a shipped policy acts in: every setting a policy acts in.
PINNED_ENV_KEYS = POLICY_KEYS

ALGOS = ("ppo", "sac")
EXPLORATIONS = ("gaussian", "gsde", "pink")
EXPLORATION_KEYS = ("exploration", "sde_sample_freq")  # AgentSpec fields of the exploration options
# AgentSpec fields that are keyword arguments of SB3's SAC under the same name, as they are (with batch_size, gamma)
SAC_KEYS = ("buffer_size", "learning_starts", "train_freq", "gradient_steps", "tau")
# AgentSpec fields that are keyword arguments of SB3's PPO under the same name, as they are
PPO_KEYS = ("n_steps", "batch_size", "n_epochs", "gamma", "gae_lambda", "clip_range", "ent_coef", "vf_coef",
            "max_grad_norm", "target_kl")

AGENTS: dict[str, AgentSpec] = {
    # Residual: gamma 0.98 (a 50-step, 50 ms horizon: several plant time constants); zero-initialised mean.
    # log_std_init -3: std exp(-3) = 0.050 action units = 0.50 mA. The exploration study (python -m
    # ehss_gym.study.exploration, -4..-1, seeds 0 and 1, 40960 steps each; reports/training/TRAINING.md, "Initial
    # exploration noise") names -3 as the largest value whose early evaluations never fell below the base law (worst
    # early score 0.946; -2 reached 1.022 and -1 3.852), and its sampled rollouts stay closest to the loop the policy
    # is scored in (exploration score 2.78 against 8.42 at -1, the first recipe's value, whose 3.7 mA noise on a
    # 10 mA valve wrecked the episodes it learned from). -4 stayed at or above the base law too but learned least.
    # target_kl limits each update. `ehss tune` was run before this value and the loop's defaults changed: it is to be
    # rerun at today's defaults.
    # residual_scale 10 mA (the current limit): an oracle friction feed-forward needs that authority to
    # halve the friction-window error (docs/ENV.md); pinned here so the agent does not follow the env default.
    "residual-ppo": AgentSpec(name="residual-ppo", mode="residual", env_kwargs=dict(RESIDUAL_ENV),
                              log_std_init=-3.0, zero_init_action=True),
    # Pure PPO: the same PPO settings, an action of current_limit (10 mA) per unit, standard init and a
    # std of exp(-1) = 0.37 (3.7 mA): it must discover tracking from scratch, so it needs to explore.
    # Its reward keeps the first recipe's rate weight 1.0 (the class reward's base-law normaliser means little to a
    # policy that starts without the law).
    # Residual SAC, the comparison algorithm: the residual agent's env, mean zero at the start (the actor's mean layer
    # zeroed: the base law) and the same initial std 0.50 mA (its log-std layer zeroed with bias -3); the entropy
    # temperature is tuned to hold the initial Gaussian's entropy (target log_std_init + log(2 pi e)/2 per action).
    # Off-policy: 8 gradient steps per 8 env steps of each of the 8 envs (one update per 64 transitions), batch 256,
    # a 200k-transition buffer, 2000 steps of the initial (base-law) policy first; lr 3e-4 constant (SAC's default).
    # Not tuned: a comparison at SB3's defaults where the residual recipe has no reason to differ.
    "residual-sac": AgentSpec(name="residual-sac", mode="residual", env_kwargs=dict(RESIDUAL_ENV), algo="sac",
                              log_std_init=-3.0, zero_init_action=True, lr_schedule="constant", net_arch=(64, 64),
                              activation="relu"),
    # Residual PPO on the observer's law: the residual agent's recipe as it is (env, reward, action, PPO settings), on
    # the velocity law whose estimator is the extended-state observer at eso-n2's bandwidth (Table I's compensator
    # rows, chosen on training scenarios of the unmodelled effects: ehss_gym.study.compensators). Where the sensors are
    # quantised that law is the best scripted velocity policy, so a residual that gains there gains over the best
    # scripted law, not over the filter's law. Velocity only: on the position task the compensator rule chose no
    # observer. Trained for 1,000,000 steps (the recipe's 300,000 left its validation curves still falling on this
    # base); shipped by the rule in docs/RL.md, "Residual PPO on the observer's law".
    "residual-ppo-eso": AgentSpec(name="residual-ppo-eso", mode="residual",
                                  env_kwargs={**RESIDUAL_ENV,
                                              **compensator_settings("eso", COMPENSATOR_ROWS["eso"]["velocity"])},
                                  log_std_init=-3.0, zero_init_action=True, tasks=("velocity",)),
    "ppo": AgentSpec(name="ppo", mode="direct", env_kwargs={**COMMON_ENV, "reward_weights": {"rate": 1.0}},
                     log_std_init=-1.0, zero_init_action=False),
}


class LinearSchedule:
    """Learning rate ``initial * progress_remaining`` (SB3 passes progress_remaining from 1 down to 0)."""

    def __init__(self, initial: float):
        self.initial = float(initial)

    def __call__(self, progress_remaining: float) -> float:
        return self.initial * progress_remaining


def agent_names() -> list[str]:
    """Valid agent names."""
    return sorted(AGENTS)


def get_spec(name: str, **overrides) -> AgentSpec:
    """The AgentSpec of ``name`` with field overrides; unknown names or fields raise ValueError."""
    if name not in AGENTS:
        raise ValueError(f"agent must be one of {agent_names()}, got {name!r}")
    spec = AGENTS[name]
    valid = sorted(set(AgentSpec.__dataclass_fields__) - {"name", "mode", "algo"})
    bad = sorted(set(overrides) - set(valid))
    if bad:
        raise ValueError(f"unknown or fixed agent hyperparameter(s) {bad}; valid: {valid}")
    d = {**asdict(spec), "net_arch": spec.net_arch}
    d.update(overrides)
    if "env_kwargs" in overrides:  # merged into the agent's env kwargs
        if not isinstance(overrides["env_kwargs"], dict):
            raise ValueError(f"env_kwargs must be a dict, got {overrides['env_kwargs']!r}")
        d["env_kwargs"] = {**spec.env_kwargs, **overrides["env_kwargs"]}
    if isinstance(d["net_arch"], (list, tuple)):
        d["net_arch"] = tuple(d["net_arch"])
    return AgentSpec(**d)


def env_kwargs_for(spec: AgentSpec, task: str, n: int) -> dict:
    """``gym.make`` keyword arguments of the training env of an agent; ValueError for a task it does not train on."""
    if task not in spec.tasks:
        raise ValueError(f"agent {spec.name!r} trains on the task(s) {list(spec.tasks)}, got task {task!r}")
    return {"task": task, "n": int(n), "mode": spec.mode, **spec.env_kwargs}


def resolved_env_kwargs(env_kwargs: dict) -> dict:
    """``env_kwargs`` with every setting of :data:`PINNED_ENV_KEYS` made explicit (the env's current defaults
    filled in), as JSON values: what an exported policy records."""
    cfg = EnvConfig.from_kwargs(env_kwargs)
    out = {k: getattr(cfg, k) for k in PINNED_ENV_KEYS}
    out["reward_weights"] = dict(cfg.reward_weights)
    if env_kwargs.get("plant") is not None:  # the rig trained on, as values (a file may change or be gone)
        out["plant"] = cfg.plant.as_dict()
    for k, v in env_kwargs.items():  # anything else given explicitly (e.g. episode_seconds) is kept
        out.setdefault(k, v)
    return out


def sac_kwargs(spec: AgentSpec) -> dict:
    """The keyword arguments of SB3's ``SAC`` that are plain numbers in ``spec`` (names as in SB3)."""
    return {"batch_size": spec.batch_size, "gamma": spec.gamma, **{k: getattr(spec, k) for k in SAC_KEYS}}


def ppo_kwargs(spec: AgentSpec) -> dict:
    """The keyword arguments of SB3's ``PPO`` that are plain numbers in ``spec`` (names as in SB3).

    The learning rate (a schedule), the policy and its keyword arguments are built by
    :mod:`ehss_gym.agents.factory` (torch objects) and written as rl-zoo3 strings by :mod:`ehss_gym.train.zoo`.
    """
    return {k: getattr(spec, k) for k in PPO_KEYS}


__all__ = ["AgentSpec", "AGENTS", "ALGOS", "EXPLORATIONS", "EXPLORATION_KEYS", "COMMON_ENV", "RESIDUAL_ENV",
           "PINNED_ENV_KEYS", "PPO_KEYS", "SAC_KEYS", "LinearSchedule", "agent_names", "get_spec", "env_kwargs_for",
           "resolved_env_kwargs", "ppo_kwargs", "sac_kwargs"]
