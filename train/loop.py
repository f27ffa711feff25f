"""Train residual PPO (or pure PPO) on EHSSTracking-v0. Reads top to bottom, like a CleanRL script.

    ehss train --agent residual-ppo --task velocity --n 2 --timesteps 300000 --seed 0
    python -m ehss_gym.train.loop --agent residual-ppo --timesteps 300000      # the same, without the CLI

1. a :class:`Config` (every field documented) -> a reproducible run name and folder;
2. :func:`make_env` builds the training env with every wrapper in sight;
3. the agent comes from :mod:`ehss_gym.agents.specs` (hyperparameters documented there);
4. custom behaviour (progress bar, held-out evaluation and best model, checkpoints, wall time) is in
   SB3 callbacks (:mod:`ehss_gym.train.callbacks`);
5. the end: the best and the final model, each as an SB3 ``.zip`` + VecNormalize ``.pkl`` and as safe
   weights (``policy.safetensors`` + ``policy.json``, :mod:`ehss_gym.agents.safeweights`), and ``summary.json``.

Run folder ``<out>`` (default ``runs/<run name>``): ``config.json`` (the full config, agent
hyperparameters and env kwargs), ``tb/`` (TensorBoard), ``checkpoints/``, ``evaluations.csv``,
``evals/best_step_<S>/``, ``best/``, ``final/``, ``summary.json``.

Resume (``--resume``) continues from ``checkpoints/latest.json``: the model with its optimizer, the
VecNormalize statistics, the step counter and the RNG states, plus the evaluation history. Episodes
that were in progress at the checkpoint are not restored (the envs start fresh episodes from their
saved generators), so a resumed run is reproducible but not bit-identical to an uninterrupted one.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
from dataclasses import dataclass

from ehss_gym.agents.specs import AGENTS, agent_names, env_kwargs_for, get_spec, resolved_env_kwargs

from . import runs

# settings that do not change the result: left out of the run-name hash
NOT_HASHED = ("out", "resume", "progress", "timesteps", "verbose")


@dataclass
class Config:
    """Everything a training run depends on."""

    agent: str = "residual-ppo"
    """agent name: residual-ppo (PPO residual on the Sontag law) or ppo (pure PPO, env mode direct)"""
    task: str = "velocity"
    """tracking task: velocity (output x2) or position (output x1)"""
    n: int = 2
    """power factor of the base CLF law (even >= 2)"""
    timesteps: int = 300_000
    """total agent steps to train for (an agent step is agent_period control periods: 1 ms for both agents)"""
    seed: int = 0
    """training seed: torch, NumPy, SB3 and the env scenario draws (sub-env i is seeded seed + i)"""
    eval_freq: int = 50_000
    """agent steps between held-out evaluations (rounded up to a rollout boundary)"""
    eval_episodes: int = 8
    """validation scenarios per evaluation (held-out seeds, disjoint from training and from the test block)"""
    eval_seconds: float = 2.0
    """duration of each validation episode [s] (2 s like the training episodes and the harness's held-out suite)"""
    checkpoint_freq: int = 50_000
    """agent steps between checkpoints (rounded up to a rollout boundary)"""
    n_envs: int | None = None
    """parallel envs (None = the agent's default)"""
    hp: dict = dataclasses.field(default_factory=dict)
    """overrides of the agent's hyperparameters (fields of ehss_gym.agents.specs.AgentSpec, e.g. {"gamma": 0.99})"""
    torch_threads: int = 1
    """torch threads of this process (runs of several seeds go one process per core)"""
    out: str | None = None
    """run folder (default runs/<run name>)"""
    resume: bool = False
    """continue from the run folder's latest checkpoint"""
    progress: bool = True
    """show a tqdm progress bar"""
    verbose: int = 0
    """SB3 verbosity"""

    def validate(self) -> Config:
        """Raise RunError naming a bad field and its accepted range."""
        if self.agent not in AGENTS:
            raise runs.RunError(f"--agent must be one of {agent_names()}, got {self.agent!r}")
        if self.task not in ("velocity", "position"):
            raise runs.RunError(f"--task must be one of ['velocity', 'position'], got {self.task!r}")
        if isinstance(self.n, bool) or not isinstance(self.n, int) or self.n < 2 or self.n % 2:
            raise runs.RunError(f"--n must be an even integer >= 2, got {self.n!r}")
        for name, low in (("timesteps", 1), ("eval_freq", 1), ("eval_episodes", 1), ("checkpoint_freq", 1),
                          ("torch_threads", 1), ("seed", 0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < low:
                raise runs.RunError(f"--{name.replace('_', '-')} must be an integer >= {low}, got {v!r}")
        if isinstance(self.eval_seconds, bool) or not isinstance(self.eval_seconds, (int, float)) \
                or not 0.01 <= self.eval_seconds <= 100.0:
            raise runs.RunError(f"--eval-seconds must be a number in [0.01, 100] (s), got {self.eval_seconds!r}")
        if self.n_envs is not None and (isinstance(self.n_envs, bool) or not isinstance(self.n_envs, int)
                                        or self.n_envs < 1):
            raise runs.RunError(f"--n-envs must be an integer >= 1, got {self.n_envs!r}")
        from ehss_gym.envs import EnvConfig

        spec = self.spec()
        try:  # the env's own validation of the kwargs the agent will train with
            EnvConfig.from_kwargs(env_kwargs_for(spec, self.task, self.n))
        except ValueError as exc:
            raise runs.RunError(f"env settings: {exc}") from None
        return self

    def spec(self):
        over = dict(self.hp)
        if self.n_envs is not None:
            over["n_envs"] = self.n_envs
        try:
            return get_spec(self.agent, **over)
        except (TypeError, ValueError) as exc:
            raise runs.RunError(f"--hp: {exc}") from None

    def full(self) -> dict:
        """The config plus the agent's hyperparameters and env kwargs: what config.json holds."""
        spec = self.spec()
        return {**dataclasses.asdict(self), "agent_spec": spec.as_dict(),
                "env_kwargs": env_kwargs_for(spec, self.task, self.n), "env_id": "EHSSTracking-v0"}

    def run_name(self) -> str:
        return runs.run_name(self.agent, self.task, self.n, self.seed, self.full(), exclude=NOT_HASHED)

    def run_dir(self) -> str:
        return self.out or os.path.join("runs", self.run_name())


def make_env(env_kwargs: dict, n_envs: int, gamma: float, norm_reward: bool):
    """The training env: ``gym.make`` -> Monitor (episode return/length for SB3's logs) -> DummyVecEnv
    (n_envs copies, stepped in turn) -> VecNormalize (running mean/std of observations, clipped at 10,
    and of the discounted return for reward scaling)."""
    import gymnasium as gym
    from stable_baselines3.common.monitor import Monitor
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    import ehss_gym  # noqa: F401  (registers EHSSTracking-v0)

    def one():
        return Monitor(gym.make("EHSSTracking-v0", **env_kwargs))

    venv = DummyVecEnv([one for _ in range(n_envs)])
    return VecNormalize(venv, norm_obs=True, norm_reward=norm_reward, clip_obs=10.0, gamma=gamma)


def env_generators(venv):
    """The sub-envs' numpy Generators (their scenario draws), for checkpointing."""
    inner = venv.venv if hasattr(venv, "venv") else venv
    return [e.unwrapped.np_random for e in inner.envs]


def export_model(model, vecnormalize, folder: str, cfg: Config, extra: dict) -> None:
    """SB3 files (model.zip, vecnormalize.pkl) and safe weights (policy.safetensors/.json) in ``folder``."""
    import pickle

    from ehss_gym.agents.safeweights import export_policy

    from ehss_gym.core.util import atomic_write

    os.makedirs(folder, exist_ok=True)
    atomic_write(os.path.join(folder, "model.zip"), lambda f: model.save(f))
    atomic_write(os.path.join(folder, "vecnormalize.pkl"), lambda f: pickle.dump(vecnormalize, f))
    full = cfg.full()
    export_policy(model, os.path.join(folder, "policy"), vecnormalize=vecnormalize, name=cfg.run_name(),
                  env_kwargs=resolved_env_kwargs(full["env_kwargs"]), metadata={"config": full, **extra})


def train(cfg: Config) -> dict:
    """Run (or resume) one training run; returns the summary dict (also written to summary.json)."""
    import torch
    from ehss_gym.agents.specs import make_agent
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import CallbackList
    from stable_baselines3.common.vec_env import VecNormalize

    from ehss_gym.core.util import atomic_write_text
    from ehss_gym.evaluation.heldout import VALIDATION_START, heldout_suite, relative_scores, run_episodes

    from .callbacks import Checkpoint, HeldoutEval, ProgressBar, WallClock

    # --- config and run folder ------------------------------------------------------------------
    cfg.validate()
    spec = cfg.spec()
    full = cfg.full()
    name = cfg.run_name()
    run_dir = cfg.run_dir()
    manifest = runs.latest_checkpoint(run_dir)
    if cfg.resume and manifest is None:
        raise runs.RunError(f"--resume: no checkpoint in {run_dir} ({runs.CKPT_DIR}/{runs.LATEST} missing); "
                            "run without --resume to start a new run")
    if not cfg.resume and manifest is not None:
        raise runs.RunError(f"{run_dir} already holds a checkpoint (step {manifest['step']}); pass --resume to "
                            "continue it or choose another --out")
    cfg_path = os.path.join(run_dir, "config.json")
    if cfg.resume and os.path.isfile(cfg_path):
        with open(cfg_path, encoding="utf-8") as f:
            old = json.load(f)
        old.pop("run_name", None)
        diff = sorted(k for k in set(old) | set(full) if k not in NOT_HASHED and old.get(k) != full.get(k))
        if diff:
            raise runs.RunError(f"--resume: settings {diff} differ from the checkpointed run in {run_dir}")
    os.makedirs(run_dir, exist_ok=True)
    atomic_write_text(cfg_path, json.dumps({**full, "run_name": name}, indent=1, default=str) + "\n")
    torch.set_num_threads(cfg.torch_threads)

    # --- env, agent ------------------------------------------------------------------------------
    env_kwargs = full["env_kwargs"]
    venv = make_env(env_kwargs, spec.n_envs, spec.gamma, spec.norm_reward)
    tb = os.path.join(run_dir, "tb")
    if manifest is None:
        model = make_agent(spec, venv, seed=cfg.seed, tensorboard_log=tb, verbose=cfg.verbose)
    else:
        venv = VecNormalize.load(manifest["vecnormalize"], venv.venv)
        model = PPO.load(manifest["model"], env=venv, device="cpu", tensorboard_log=tb, verbose=cfg.verbose)

    # --- held-out validation scenarios and the base law on them ------------------------------------
    base_kwargs = {k: v for k, v in env_kwargs.items() if k not in ("mode", "residual_scale")}
    scenarios = heldout_suite(env_kwargs, cfg.eval_episodes, VALIDATION_START, cfg.eval_seconds)
    base = run_episodes({**base_kwargs, "mode": "residual"}, scenarios)  # the agent's own base law
    reference = base if cfg.n == 2 else run_episodes({**base_kwargs, "mode": "residual", "n": 2},
                                                     [sc.replace(n=2) for sc in scenarios])  # the score's reference

    # --- callbacks -------------------------------------------------------------------------------
    wall = WallClock()
    evaluator = HeldoutEval(run_dir, env_kwargs, scenarios, base, reference, cfg.eval_freq, wall)
    checkpoint = Checkpoint(run_dir, cfg.checkpoint_freq, {"wall": wall, "eval": evaluator},
                            lambda: env_generators(venv))
    progress = ProgressBar(cfg.timesteps, desc=name, disable=not cfg.progress)
    if manifest is not None:
        state = runs.read_state(manifest["state"])
        wall.load_state_dict(state["callbacks"]["wall"])
        evaluator.load_state_dict(state["callbacks"]["eval"], manifest["step"])
        runs.restore_rng(state["rng"], env_generators(venv))  # PPO.load re-seeded everything from cfg.seed
        venv.venv._seeds = [None] * venv.num_envs  # ... and queued env seeds; keep the restored generators
    callbacks = CallbackList([wall, progress, evaluator, checkpoint])

    # --- learn -----------------------------------------------------------------------------------
    remaining = cfg.timesteps - model.num_timesteps
    if remaining > 0:
        model.learn(total_timesteps=remaining, callback=callbacks, reset_num_timesteps=manifest is None,
                    tb_log_name="PPO", progress_bar=False)
    checkpoint.init_callback(model)
    checkpoint.save()  # a finished run can be extended with --resume --timesteps LARGER

    # --- the best and the final model --------------------------------------------------------------
    wall_s = wall.seconds
    best = evaluator.history[[r["step"] for r in evaluator.history].index(evaluator.best_step)]
    export_model(model, venv, os.path.join(run_dir, "final"), cfg,
                 {"step": int(model.num_timesteps), "validation": evaluator.history[-1]})
    best_model = PPO.load(os.path.join(evaluator.best_dir(), "model.zip"), device="cpu")
    best_vn = VecNormalize.load(os.path.join(evaluator.best_dir(), "vecnormalize.pkl"), venv.venv)
    export_model(best_model, best_vn, os.path.join(run_dir, "best"), cfg,
                 {"step": int(evaluator.best_step), "validation": best})
    summary = {"run_name": name, "run_dir": run_dir, "agent": cfg.agent, "task": cfg.task, "n": cfg.n,
               "seed": cfg.seed, "timesteps": int(model.num_timesteps), "wall_s": round(wall_s, 2),
               "best_step": evaluator.best_step, "best_validation": best,
               "base_validation": relative_scores(base, base, reference),
               "final_validation": evaluator.history[-1]}
    atomic_write_text(os.path.join(run_dir, "summary.json"), json.dumps(summary, indent=1) + "\n")
    venv.close()
    return summary


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    """Command-line arguments of :class:`Config` (shared by ``ehss train`` and ``python -m``)."""
    p = parser or argparse.ArgumentParser(prog="python -m ehss_gym.train.loop", description=__doc__.split("\n")[0])
    p.add_argument("--agent", default="residual-ppo", help=f"one of {agent_names()}")
    p.add_argument("--task", default="velocity", help="velocity or position")
    p.add_argument("--n", default="2", help="base-law power factor (even >= 2)")
    p.add_argument("--timesteps", default=str(Config.timesteps), help="total agent steps")
    p.add_argument("--seed", default=None, help="training seed (integer >= 0; default 0)")
    p.add_argument("--seeds", default=None, help="several seeds, e.g. 0-4 or 0,2,5: one process per core")
    p.add_argument("--jobs", default=None, help="parallel processes for --seeds (default: the usable cores)")
    p.add_argument("--eval-freq", default=str(Config.eval_freq), help="agent steps between evaluations")
    p.add_argument("--eval-episodes", default=str(Config.eval_episodes), help="validation scenarios")
    p.add_argument("--eval-seconds", default=str(Config.eval_seconds), help="validation episode duration [s]")
    p.add_argument("--checkpoint-freq", default=str(Config.checkpoint_freq), help="agent steps between checkpoints")
    p.add_argument("--n-envs", default=None, help="parallel envs (default: the agent's)")
    p.add_argument("--hp", action="append", default=[], metavar="KEY=JSON",
                   help="override an agent hyperparameter (ehss_gym.agents.specs.AgentSpec), e.g. --hp gamma=0.99 "
                        "--hp 'env_kwargs={\"agent_period\": 20}'; repeatable")
    p.add_argument("--out", default=None, help="run folder (default runs/<run name>; with --seeds: the parent)")
    p.add_argument("--resume", action="store_true", help="continue from the latest checkpoint")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


def _int(name: str, text, low: int) -> int:
    try:
        v = int(text)
    except (TypeError, ValueError):
        raise runs.RunError(f"--{name} must be an integer >= {low}, got {text!r}") from None
    if v < low:
        raise runs.RunError(f"--{name} must be an integer >= {low}, got {text!r}")
    return v


def _float(name: str, text) -> float:
    try:
        return float(text)
    except (TypeError, ValueError):
        raise runs.RunError(f"--{name} must be a number, got {text!r}") from None


def parse_hp(items) -> dict:
    """``KEY=JSON`` strings -> dict; RunError on a malformed item."""
    out = {}
    for item in items or []:
        key, sep, val = item.partition("=")
        if not sep or not key.strip():
            raise runs.RunError(f"--hp must be KEY=JSON (e.g. gamma=0.99), got {item!r}")
        try:
            out[key.strip()] = json.loads(val)
        except ValueError:
            raise runs.RunError(f"--hp {key.strip()}: value {val!r} is not JSON (strings need quotes)") from None
    return out


def config_from_args(args, seed: int | None = None, out: str | None = None) -> Config:
    """A validated Config from parsed arguments (``seed``/``out`` override, for multi-seed runs)."""
    try:
        n = int(args.n)
    except ValueError:
        raise runs.RunError(f"--n must be an even integer >= 2, got {args.n!r}") from None
    cfg = Config(agent=args.agent, task=args.task, n=n, timesteps=_int("timesteps", args.timesteps, 1),
                 seed=seed if seed is not None else _int("seed", args.seed if args.seed is not None else 0, 0),
                 eval_freq=_int("eval-freq", args.eval_freq, 1), eval_episodes=_int("eval-episodes",
                                                                                    args.eval_episodes, 1),
                 checkpoint_freq=_int("checkpoint-freq", args.checkpoint_freq, 1),
                 eval_seconds=_float("eval-seconds", args.eval_seconds),
                 n_envs=None if args.n_envs is None else _int("n-envs", args.n_envs, 1), hp=parse_hp(args.hp),
                 out=out if out is not None else args.out, resume=args.resume, progress=not args.no_progress)
    return cfg.validate()


def main(argv=None) -> int:
    from ehss_gym.cli.train import run_from_args

    return run_from_args(build_parser().parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())


__all__ = ["Config", "make_env", "train", "export_model", "build_parser", "config_from_args"]
