"""Training cost: Stable-Baselines3 PPO on EHSSTracking-v0 against Pendulum-v1, same hyperparameters; the
residual-PPO recipe trained on the native vector env through the SB3 adapter against SB3's DummyVecEnv, side
by side; and the wall time of one seed of the shipped residual-PPO recipe (target: <= 30 min on 2 CPU cores).

Both runs use the same PPO settings on the CPU with one torch thread (the two cores
are shared, and one thread keeps the two sides comparable). The env is wrapped in a
timer, so the report shows how much of the training wall time is spent inside
``env.step``/``env.reset`` and how much in PPO itself (rollout bookkeeping, the
policy forward passes and the gradient updates).
"""

from __future__ import annotations

import json
import os
import tempfile
import time

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.logger import Logger

from ehss_gym.agents.factory import make_agent
from ehss_gym.agents.specs import env_kwargs_for, get_spec
from ehss_gym.train.loop import Config, make_env, train

from . import bench_env
from .common import Section, Table, Target, interleave, log, median, spread

RECIPE_STEPS = Config.timesteps  # agent steps of one shipped residual-PPO run: the training config's default
K_STEPS = f"{RECIPE_STEPS // 1000}k steps"
TRAIN_TARGET_S = 30 * 60.0  # [s] the target: wall time per seed to the reported policy

PPO_KW = dict(n_steps=256, batch_size=64, n_epochs=4, learning_rate=3e-4, gamma=0.99, seed=0, device="cpu",
              verbose=0)


class EnvTimer(gym.Wrapper):
    """Accumulates the wall time spent in the wrapped env's step and reset [s]."""

    def __init__(self, env):
        super().__init__(env)
        self.seconds = 0.0
        self.calls = 0

    def step(self, action):
        t0 = time.perf_counter()
        out = self.env.step(action)
        self.seconds += time.perf_counter() - t0
        self.calls += 1
        return out

    def reset(self, **kwargs):
        t0 = time.perf_counter()
        out = self.env.reset(**kwargs)
        self.seconds += time.perf_counter() - t0
        return out


def ppo_run(make_env, total_steps: int, record: list) -> float:
    """Train PPO for total_steps; returns the learn() wall time [s] and appends (learn s, env s) to record."""
    env = EnvTimer(make_env())
    model = PPO("MlpPolicy", env, **PPO_KW)
    model.set_logger(Logger(None, []))  # no SB3-<time> folder in the system's temporary folder per learn()
    t0 = time.perf_counter()
    model.learn(total_timesteps=total_steps)
    dt = time.perf_counter() - t0
    record.append((dt, env.seconds))
    env.close()
    return dt


def run(quick: bool) -> Section:
    sec = Section("train", "3. Training: SB3 PPO steps per second")
    status = bench_env.env_status()
    if status:
        sec.skipped = status
        return sec
    steps = 512 if quick else 4096
    reps = 1 if quick else 3
    sec.note(f"PPO('MlpPolicy', {', '.join(f'{k}={v!r}' for k, v in PPO_KW.items())}), {steps} steps per run, "
             f"torch {torch.__version__} with 1 thread; model construction is outside the timing.")
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        rec = {"EHSSTracking-v0 (ours)": [], "Pendulum-v1": []}
        makers = {"EHSSTracking-v0 (ours)": bench_env.make_ours, "Pendulum-v1": bench_env.make_pendulum}
        ppo_run(makers["Pendulum-v1"], 64 if quick else 256, [])  # warm torch and SB3 code paths
        log(f"train: PPO {steps} steps x {reps} repeats on each env, interleaved")
        times = interleave({k: (lambda k=k: ppo_run(makers[k], steps, rec[k])) for k in makers}, reps)
    finally:
        torch.set_num_threads(threads)
    tb = Table("ppo_training", "PPO training throughput (median of interleaved repeats)",
               ["env", "median_learn_s", "min..max_s", "steps_per_s", "vs_Pendulum-v1", "env_share_of_time",
                "ppo_overhead_s_per_1k_steps"])
    pend_rate = steps / median(times["Pendulum-v1"])
    for k, ts in times.items():
        share = median([e / t for t, e in rec[k]])
        overhead = median([(t - e) / steps * 1000 for t, e in rec[k]])
        tb.add(k, median(ts), spread(ts), steps / median(ts), steps / median(ts) / pend_rate, share, overhead)
    sec.tables.append(tb)
    ours = median([e / t for t, e in rec["EHSSTracking-v0 (ours)"]])
    sec.note(f"The env accounts for {ours:.0%} of PPO's wall time on EHSSTracking-v0 (env step/reset time measured "
             "by a wrapper around the env); the rest is SB3/torch (rollout buffer, policy forward passes, updates).")
    vec_env_throughput(sec, quick)
    recipe_cost(sec, quick, pend_rate)
    return sec


def recipe_run(native: bool, steps: int, n_envs: int) -> float:
    """Train the residual-PPO recipe (its hyperparameters, ``n_envs`` envs) for ``steps`` agent steps on the native
    vector env adapter (``native``) or SB3's DummyVecEnv; returns the learn() wall time [s] (construction excluded)."""
    spec = get_spec("residual-ppo")
    venv = make_env(env_kwargs_for(spec, "velocity", 2), n_envs, spec.gamma, spec.norm_reward, native=native)
    model = make_agent(spec, venv, seed=0)
    model.set_logger(Logger(None, []))
    t0 = time.perf_counter()
    model.learn(total_timesteps=steps)
    dt = time.perf_counter() - t0
    venv.close()
    return dt


def step_run(native: bool, steps: int, n_envs: int) -> float:
    """Step the recipe's VecNormalize-wrapped training env (``n_envs`` envs) with zero actions for ``steps`` agent
    steps, no policy; returns the wall time [s] (construction and the first reset excluded)."""
    spec = get_spec("residual-ppo")
    venv = make_env(env_kwargs_for(spec, "velocity", 2), n_envs, spec.gamma, spec.norm_reward, native=native)
    venv.seed(0)
    venv.reset()
    actions = np.zeros((n_envs, *venv.action_space.shape), dtype=np.float32)
    t0 = time.perf_counter()
    for _ in range(steps // n_envs):
        venv.step(actions)
    dt = time.perf_counter() - t0
    venv.close()
    return dt


VEC_ENV_SIZES = (8, 32, 64)  # envs per run: the recipe's 8, and the 32-64 a larger recipe would use


def vec_env_throughput(sec: Section, quick: bool) -> None:
    """PPO training throughput of the residual-PPO recipe on the native vector env (one compiled call for all its
    envs, through ``ehss_gym.train.vec_env.NativeVecEnv``) against SB3's DummyVecEnv of single envs (stepped in
    turn), at 8, 32 and 64 envs (--quick: 8): the same seed gives the same weights on both, so only the time
    differs. Every run takes as many agent steps (whole rollouts of the largest size)."""
    spec = get_spec("residual-ppo")
    sizes = VEC_ENV_SIZES[:1] if quick else VEC_ENV_SIZES
    steps = max(sizes) * spec.n_steps * (1 if quick else 2)
    reps = 1 if quick else 3
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    cases = {"native vector env (NativeVecEnv)": True, "DummyVecEnv of single envs": False}
    times, env_times = {}, {}
    try:
        recipe_run(True, spec.n_envs * spec.n_steps, spec.n_envs)  # warm the compiled kernels and torch
        for n in sizes:
            log(f"train: residual-ppo recipe at {n} envs, {steps} steps x {reps} repeats, native vector env vs "
                "DummyVecEnv, interleaved")
            times[n] = interleave({k: (lambda v=v, n=n: recipe_run(v, steps, n)) for k, v in cases.items()}, reps)
            env_times[n] = interleave({k: (lambda v=v, n=n: step_run(v, steps, n)) for k, v in cases.items()}, reps)
    finally:
        torch.set_num_threads(threads)
    tb = Table("ppo_vec_env", "PPO training throughput of the residual-PPO recipe by vector env and number of envs "
               "(median of interleaved repeats)", ["n_envs", "vector env", "median_learn_s", "min..max_s",
                                                   "steps_per_s", "vs_DummyVecEnv", "env_only_steps_per_s",
                                                   "env_only_vs_DummyVecEnv"])
    dummy, native = "DummyVecEnv of single envs", "native vector env (NativeVecEnv)"
    gains = {}
    for n in sizes:
        rate = {k: steps / median(ts) for k, ts in times[n].items()}
        env_rate = {k: steps / median(ts) for k, ts in env_times[n].items()}
        for k, ts in times[n].items():
            tb.add(n, k, median(ts), spread(ts), rate[k], rate[k] / rate[dummy], env_rate[k],
                   env_rate[k] / env_rate[dummy])
        gains[n] = (rate[native] / rate[dummy], env_rate[native] / env_rate[dummy], rate[native] / env_rate[native])
    sec.tables.append(tb)
    per_size = "; ".join(f"{n} envs: {g:.2f}x (env alone {e:.2f}x; the env {share:.0%} of training's time)"
                         for n, (g, e, share) in gains.items())
    sec.note(f"Residual-PPO recipe ({spec.n_steps} steps per env and rollout, {spec.n_epochs} epochs, velocity n = 2, "
             f"seed 0), {steps} agent steps per run, 1 torch thread. Training on the native vector env against SB3's "
             f"DummyVecEnv, in steps per second: {per_size}. Both give identical weights for the same seed "
             "(tests/test_train.py). Stepping the env alone (zero actions, no policy, VecNormalize included) gains "
             "more than training does: the rest of training is the policy's forward passes and the PPO updates.")


def recipe_cost(sec: Section, quick: bool, pend_rate: float) -> None:
    """One seed of the shipped residual-PPO recipe through ``ehss_gym.train.loop.train`` (progress bar off;
    held-out evaluations, checkpoints and exports included), next to PPO on Pendulum-v1 for as many steps
    with the throughput measured above. --quick trains 1/100 of the steps and extrapolates linearly."""
    steps = RECIPE_STEPS // 100 if quick else RECIPE_STEPS
    log(f"train: residual-ppo velocity n=2 seed 0, {steps} agent steps (the shipped recipe's settings)")
    with tempfile.TemporaryDirectory() as tmp:
        cfg = Config(agent="residual-ppo", task="velocity", n=2, seed=0, timesteps=steps,
                     eval_freq=max(steps // 8, 1), eval_episodes=24, checkpoint_freq=max(steps // 8, 1),
                     out=os.path.join(tmp, "run"), progress=False)
        t0 = time.perf_counter()
        train(cfg)
        wall = time.perf_counter() - t0
        summary = json.load(open(os.path.join(tmp, "run", "summary.json"), encoding="utf-8"))
    per_seed = wall * RECIPE_STEPS / steps
    pend_s = RECIPE_STEPS / pend_rate  # [s] PPO on Pendulum-v1 at the throughput measured above
    tb = Table("training_cost", "Wall time of one seed of the shipped residual-PPO recipe",
               ["run", "agent_steps", "wall_s", f"per_seed_s ({K_STEPS})", "best_step", f"pendulum_ppo_s ({K_STEPS})",
                "vs_pendulum_ppo"])
    tb.add("residual-ppo velocity n=2 seed 0", steps, wall, per_seed, summary.get("best_step"), pend_s,
           per_seed / pend_s)
    sec.tables.append(tb)
    sec.targets.append(Target(f"wall time per seed of the residual-PPO recipe ({K_STEPS})", per_seed / 60.0,
                              TRAIN_TARGET_S / 60.0, unit="min", lower_is_better=True,
                              note="extrapolated from 1/100 of the steps" if quick else ""))
    sec.note(f"One seed of the recipe: {per_seed / 60:.1f} min for {RECIPE_STEPS} agent steps "
             + ("(extrapolated from a 1/100 run) " if quick else "")
             + "including 8 held-out evaluations of 24 episodes, checkpoints and the safe-weight exports; PPO on "
             f"Pendulum-v1 with the throughput above would take {pend_s / 60:.1f} min for as many steps (without "
             "evaluations). Several seeds run one process per core (`ehss train --seeds 0-4`).")
