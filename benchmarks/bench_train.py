"""Training cost: Stable-Baselines3 PPO on EHSSTracking-v0 against Pendulum-v1, same hyperparameters.

Both runs use the same PPO settings on the CPU with one torch thread (the two cores
are shared, and one thread keeps the two sides comparable). The env is wrapped in a
timer, so the report shows how much of the training wall time is spent inside
``env.step``/``env.reset`` and how much in PPO itself (rollout bookkeeping, the
policy forward passes and the gradient updates).
"""

from __future__ import annotations

import time

import gymnasium as gym

from . import bench_env
from .common import Section, Table, interleave, log, median, spread

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
    from stable_baselines3 import PPO

    env = EnvTimer(make_env())
    model = PPO("MlpPolicy", env, **PPO_KW)
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
    import torch

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
    return sec
