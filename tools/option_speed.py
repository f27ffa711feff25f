"""Training speed of the recipe's options, as ratios to the recipe in one run.

Usage::

    python tools/option_speed.py [--steps 16384] [--task position]

Each option trains the residual agent (PPO, :func:`ehss_gym.agents.factory.make_agent` on
:func:`ehss_gym.train.loop.make_env`, the native vector env) for ``--steps`` agent steps from a fresh model, after
one warm-up run of the recipe (torch's and numba's first calls). Printed per option: the process CPU time and the
wall time per 1000 agent steps, agent steps per CPU second, and its ratio to the recipe's (steps/s of the option over
the recipe's; the ratio is what compares on a shared machine, CPU time rather than wall time).
"""

from __future__ import annotations

import argparse
import time

import torch

from ehss_gym.agents.factory import make_agent
from ehss_gym.agents.specs import get_spec
from ehss_gym.train.loop import make_env

OPTIONS = {  # name -> AgentSpec overrides (env_kwargs merged into the agent's)
    "recipe (8 envs, white noise, current action)": {},
    "unmodelled effects": {"env_kwargs": {"unmodelled_effects": True}},
    "gSDE": {"exploration": "gsde"},
    "pink noise": {"exploration": "pink"},
    "32 envs": {"n_envs": 32},
    "64 envs": {"n_envs": 64},
    "action rate": {"env_kwargs": {"action": "rate"}},
    "action filtered": {"env_kwargs": {"action": "filtered"}},
    "action reference": {"env_kwargs": {"action": "reference"}},
    "action schedule": {"env_kwargs": {"action": "schedule"}},
}


def timed(task: str, overrides: dict, steps: int) -> tuple[float, float]:
    """(CPU seconds, wall seconds) of ``steps`` agent steps of training with ``overrides``."""
    spec = get_spec("residual-ppo", **overrides)
    venv = make_env({"task": task, "n": 2, "mode": "residual", **spec.env_kwargs}, spec.n_envs, spec.gamma,
                    spec.norm_reward)
    model = make_agent(spec, venv, seed=0)
    c0, w0 = time.process_time(), time.perf_counter()
    model.learn(steps)
    return time.process_time() - c0, time.perf_counter() - w0


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=16384, help="agent steps per option (default 16384)")
    ap.add_argument("--task", default="position", choices=("velocity", "position"))
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    timed(args.task, {}, 2048)  # warm-up
    base = None
    for name, over in OPTIONS.items():
        cpu, wall = timed(args.task, over, args.steps)
        rate = args.steps / cpu
        base = base or rate
        print(f"{name:45s} CPU {1000 * cpu / args.steps:6.2f} s, wall {1000 * wall / args.steps:6.2f} s per 1000 steps;"
              f" {rate:7.0f} steps per CPU s, x{rate / base:.2f} the recipe's", flush=True)


if __name__ == "__main__":
    main()
