"""The exploration-noise study: the measurement behind the residual agent's initial exploration noise
(``log_std_init``, the std of PPO's Gaussian actions; not the sensor noise of ``ehss noise``).

    python -m ehss_gym.study.exploration --out reports/training/exploration_noise.json

For each candidate ``log_std_init`` (Gaussian std in action units; one unit = ``residual_scale`` mA):

1. *exploration cost*: the untrained residual policy (mean exactly 0) sampled stochastically, as PPO's
   rollouts are, on the validation scenarios; its overall figure against the base law (1 = the base law;
   :mod:`ehss_gym.evaluation.heldout`);
2. *early evaluations*: a short training run (same seed, same everything else) evaluated
   deterministically every ``eval_freq`` steps; the worst (largest) figure of those early evaluations,
   and whether any fell below the base law (figure > 1, or the failure gate failed).

The criterion of the design is that early evaluations do not fall below the base law; the study
reports, for each candidate, whether they did (``below_base``) and the largest candidate that passed
(``largest_safe_log_std_init``, None if none did), next to the value the agent uses.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import sys
import time

import numpy as np

from ehss_gym.agents.specs import env_kwargs_for, get_spec, resolved_env_kwargs
from ehss_gym.evaluation.heldout import VALIDATION_START, floors_of, heldout_suite, relative_scores, run_episodes
from ehss_gym.infra.util import atomic_write_text
from ehss_gym.train.config import Config
from ehss_gym.train.loop import train

COMMAND = "python -m ehss_gym.study.exploration"  # the command that runs this study (its JSON records it)

CANDIDATES = (-4.0, -3.0, -2.0, -1.0)


def stochastic_zero_policy(std: float, seed: int):
    """Actions N(0, std^2), clipped to [-1, 1] like the env clips: the untrained residual's rollouts."""
    rng = np.random.default_rng(seed)
    return lambda obs: np.clip(std * rng.standard_normal((len(obs), 1)), -1.0, 1.0).astype(np.float32)


def run(candidates=CANDIDATES, timesteps: int = 40_960, eval_freq: int = 8_192, episodes: int = 16,
        seeds=(0, 1), workdir: str = "runs/exploration_noise", progress: bool = False) -> dict:
    """The study (see the module docstring); returns a JSON-able dict."""
    spec = get_spec("residual-ppo")
    kw = env_kwargs_for(spec, "velocity", 2)
    scale = resolved_env_kwargs(kw)["residual_scale"]  # [mA] per action unit
    scenarios = heldout_suite(kw, episodes, VALIDATION_START)
    base = run_episodes(kw, scenarios)
    rows = []
    for v in candidates:
        t0 = time.perf_counter()
        explore = relative_scores(run_episodes(kw, scenarios, stochastic_zero_policy(math.exp(v), 0)), base, None,
                                  floors_of(kw))
        early = {}
        for seed in seeds:
            out = os.path.join(workdir, f"log_std_{v:g}_s{seed}")
            if os.path.isdir(out):
                shutil.rmtree(out)  # the study always starts fresh
            cfg = Config(agent="residual-ppo", task="velocity", n=2, timesteps=timesteps, seed=seed,
                         eval_freq=eval_freq, eval_episodes=episodes, checkpoint_freq=10**9, out=out,
                         progress=progress, hp={"log_std_init": v, "lr_schedule": "constant"})  # early phase
            train(cfg)
            with open(os.path.join(out, "evaluations.json"), encoding="utf-8") as f:
                early[seed] = [r for r in json.load(f) if r["step"] > 0]
        figs = [r["figure"] for seed in seeds for r in early[seed]]
        failed = any(r["failed"] for seed in seeds for r in early[seed])
        rows.append({"log_std_init": v, "std_action": math.exp(v), "std_mA": math.exp(v) * scale,
                     "explore_figure": explore["figure"], "explore_failed": explore["failed"],
                     "explore_rel_tracking": explore["rel_tracking"], "explore_rel_effort": explore["rel_effort"],
                     "early_steps": [r["step"] for r in early[seeds[0]]],
                     "early_figures": {str(seed): [r["figure"] for r in early[seed]] for seed in seeds},
                     "mean_early_figure": float(np.mean(figs)), "worst_early_figure": max(figs),
                     "below_base": failed or any(x > 1.0 for x in figs), "wall_s": time.perf_counter() - t0})
    ok = [r["log_std_init"] for r in rows if not r["below_base"]]
    return {"command": COMMAND, "timesteps": timesteps, "eval_freq": eval_freq,
            "episodes": episodes, "seeds": list(seeds), "env_kwargs": resolved_env_kwargs(kw), "rows": rows,
            "largest_safe_log_std_init": max(ok) if ok else None, "chosen_log_std_init": spec.log_std_init}


def main(argv=None) -> int:
    """Run the study from the command line and write its JSON."""
    p = argparse.ArgumentParser(prog=COMMAND, description=__doc__.split("\n")[0])
    p.add_argument("--out", default=os.path.join("reports", "training", "exploration_noise.json"),
                   help="the JSON written (default: %(default)s)")
    p.add_argument("--timesteps", type=int, default=40_960, help="steps of each short run (default: %(default)s)")
    p.add_argument("--episodes", type=int, default=16, help="validation episodes (default: %(default)s)")
    p.add_argument("--workdir", default=os.path.join("runs", "exploration_noise"),
                   help="the short training runs' folder (default: %(default)s)")
    args = p.parse_args(argv)
    res = run(timesteps=args.timesteps, episodes=args.episodes, workdir=args.workdir)
    atomic_write_text(args.out, json.dumps(res, indent=1) + "\n")
    for r in res["rows"]:
        print(f"log_std_init {r['log_std_init']:+.0f} (std {r['std_mA']:.2f} mA): exploration figure "
              f"{r['explore_figure']:.3f}, early evaluation figures {r['early_figures']}")
    print(f"largest log_std_init whose early evaluations stayed at or above the base law: "
          f"{res['largest_safe_log_std_init']}; wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
