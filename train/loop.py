"""Train residual PPO (or pure PPO, or residual SAC for comparison) on EHSSTracking-v0. Reads top to bottom, like a
CleanRL script.

    python -m ehss_gym.train.loop --agent residual-ppo --task velocity --n 2 --timesteps 300000 --seed 0
    ehss train --agent residual-ppo --seeds 0-4          # several seeds, one process each (ehss_gym.train.launch)

1. a :class:`~ehss_gym.train.config.Config` (every field documented; the flags are its fields) -> a
   reproducible run name and folder;
2. :func:`make_env` builds the training env with every wrapper in sight: the native vector env as an SB3
   VecEnv (:class:`~ehss_gym.train.vec_env.NativeVecEnv`: all envs in one compiled call), then VecNormalize;
3. the agent comes from :mod:`ehss_gym.agents.factory` (hyperparameters in :mod:`ehss_gym.agents.specs`);
4. custom behaviour (progress bar, held-out evaluation and best model, checkpoints, wall time) is in
   SB3 callbacks (:mod:`ehss_gym.train.callbacks`);
5. the end: the best and the final model, each as an SB3 ``.zip`` + VecNormalize ``.pkl`` and as safe weights
   (``policy.safetensors`` + ``policy.json``, :mod:`ehss_gym.agents.export`; SAC's actor with the format's squashed
   head), and ``summary.json``. A resumed SAC run restarts with an
   empty replay buffer (checkpoints hold the model, not the buffer).

Run folder ``<out>`` (default ``runs/<run name>``): ``config.json`` (the full config, agent
hyperparameters and env kwargs), ``tb/`` (TensorBoard), ``checkpoints/``, ``evaluations.csv``,
``evals/best_step_<S>/``, ``best/``, ``final/``, ``summary.json``.

Resume (``--resume``) continues from ``checkpoints/latest.json``: the model with its optimizer, the
VecNormalize statistics, the step counter and the RNG states, plus the evaluation history. Episodes
that were in progress at the checkpoint are not restored (the envs start fresh episodes from their
saved generators), so a resumed run is reproducible but not bit-identical to an uninterrupted one.
"""

from __future__ import annotations

import json
import os
import pickle
import sys
from collections.abc import Callable

import gymnasium as gym
import torch
from stable_baselines3 import PPO, SAC
from stable_baselines3.common.callbacks import CallbackList
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

from ehss_gym.agents.export import export_policy
from ehss_gym.agents.factory import make_agent
from ehss_gym.agents.specs import resolved_env_kwargs
from ehss_gym.envs import ENV_ID
from ehss_gym.envs.config import ADDON_KEYS, plant_of, reference_law_kwargs
from ehss_gym.evaluation.heldout import VALIDATION_START, floors_of, heldout_suite, relative_scores, run_episodes
from ehss_gym.infra.execution import pin_blas
from ehss_gym.infra.fmt import fmt_num
from ehss_gym.infra.util import atomic_write, atomic_write_text

from . import runs
from .callbacks import Checkpoint, HeldoutEval, ProgressBar, WallClock, restore_rng
from .config import NOT_HASHED, Config, build_parser, config_from_args
from .vec_env import NativeVecEnv

CLIP_OBS = 10.0  # VecNormalize's clip of the normalised observations [std]
ALGO_CLASSES = {"ppo": PPO, "sac": SAC}  # AgentSpec.algo -> the SB3 class that saves and loads its models


# --- the env --------------------------------------------------------------------------------------------


def make_env(env_kwargs: dict, n_envs: int, gamma: float, norm_reward: bool, native: bool = True) -> VecNormalize:
    """The training env: ``n_envs`` EHSSTracking-v0 envs -> VecNormalize (running mean/std of the observations,
    clipped at :data:`CLIP_OBS`, and of the discounted return, ``gamma``, for reward scaling).

    Args:
        env_kwargs: keyword arguments of ``EHSSTracking-v0``.
        n_envs: parallel envs.
        gamma: discount of VecNormalize's return statistics (the agent's).
        norm_reward: scale rewards by the running return std.
        native: the native vector env as one SB3 VecEnv (default); False: SB3's DummyVecEnv of
            ``Monitor(gym.make(...))`` envs stepped in turn (the same numbers, slower; kept for comparison).
    """
    if native:
        venv = NativeVecEnv(n_envs, env_kwargs)
    else:
        venv = DummyVecEnv([lambda: Monitor(gym.make(ENV_ID, **env_kwargs)) for _ in range(n_envs)])
    return VecNormalize(venv, norm_obs=True, norm_reward=norm_reward, clip_obs=CLIP_OBS, gamma=gamma)


def env_generators(venv) -> list:
    """The sub-envs' numpy Generators (their scenario draws), for checkpointing."""
    return (venv.venv if isinstance(venv, VecNormalize) else venv).get_attr("np_random")


# --- the run folder ---------------------------------------------------------------------------------------


def open_run(cfg: Config) -> dict | None:
    """Check the run folder against ``--resume``, write ``config.json``; the checkpoint manifest to resume or None."""
    full = cfg.full()
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
    atomic_write_text(cfg_path, json.dumps({**full, "run_name": cfg.run_name()}, indent=1, default=str) + "\n")
    return manifest


def export_model(model, vecnormalize, folder: str, cfg: Config, extra: dict) -> None:
    """SB3 files (model.zip, vecnormalize.pkl, and model.json: every env setting the model acts in, so that
    ``ehss evaluate --policies sb3:<folder>/model.zip`` scores it in its own loop) and safe weights
    (policy.safetensors/.json; PPO's Gaussian head, SAC's squashed one) in ``folder``."""
    os.makedirs(folder, exist_ok=True)
    atomic_write(os.path.join(folder, "model.zip"), lambda f: model.save(f))
    atomic_write(os.path.join(folder, "vecnormalize.pkl"), lambda f: pickle.dump(vecnormalize, f))
    full = cfg.full()
    env_kwargs = resolved_env_kwargs(full["env_kwargs"])
    atomic_write_text(os.path.join(folder, "model.json"), json.dumps({"env_kwargs": env_kwargs}, indent=1) + "\n")
    export_policy(model, os.path.join(folder, "policy"), vecnormalize=vecnormalize, name=cfg.run_name(),
                  env_kwargs=env_kwargs, metadata={"config": full, **extra})


# --- validation -------------------------------------------------------------------------------------------


def validation(cfg: Config, env_kwargs: dict) -> tuple[list, list[dict], list[dict]]:
    """The validation scenarios, the agent's base law on them (with its add-ons: a residual on top of a compensator
    starts as the compensated law) and the figures' reference (the n = 2 law without add-ons, the ruler's)."""
    base_kwargs = {k: v for k, v in env_kwargs.items() if k not in ("mode", "residual_scale")}
    scenarios = heldout_suite(env_kwargs, cfg.eval_episodes, VALIDATION_START, cfg.eval_seconds)
    base = run_episodes({**base_kwargs, "mode": "residual"}, scenarios)  # the agent's own base law
    # the reference is the n = 2 law at its own settings: the same episodes (a pure function of their seeds) drawn
    # for its loop, which differs from this n's in more than n where the law's defaults are tuned per n
    ref_kwargs = reference_law_kwargs(base_kwargs)
    same = cfg.n == 2 and not any(k in base_kwargs for k in ADDON_KEYS)
    reference = base if same else run_episodes(
        ref_kwargs, heldout_suite(ref_kwargs, cfg.eval_episodes, VALIDATION_START, cfg.eval_seconds))
    return scenarios, base, reference


# --- training ---------------------------------------------------------------------------------------------


def rollout_note(timesteps: int, start: int, rollout: int) -> str | None:
    """What a run of ``--timesteps`` from step ``start`` will really do, when that is not what was asked.

    PPO collects whole rollouts (``rollout`` = n_envs * n_steps agent steps; SAC n_envs * train_freq), so it stops at
    the first rollout boundary at or past ``timesteps``; a resumed run already at or past it trains nothing.
    """
    if start >= timesteps:
        return (f"the run is already at step {start} (--timesteps {timesteps}); nothing to train, the final and "
                "best models are exported again")
    end = start + -(-(timesteps - start) // rollout) * rollout
    if end != timesteps:
        return (f"--timesteps {timesteps} is not a whole number of rollouts ({rollout} agent steps = n_envs x "
                f"n_steps, or SAC's n_envs x train_freq) from step {start}; training runs to step {end}")
    return None


def train(cfg: Config, on_eval: Callable[[dict], None] | None = None) -> dict:
    """Run (or resume) one training run; returns the summary dict (also written to summary.json).

    Args:
        cfg: the run's settings.
        on_eval: called with every held-out validation row (:class:`~ehss_gym.train.callbacks.HeldoutEval`).
    """
    cfg.validate()
    pin_blas()  # before torch's first computation: the run's numbers do not depend on the CPU's instruction set
    spec, full, name, run_dir = cfg.spec(), cfg.full(), cfg.run_name(), cfg.run_dir()
    manifest = open_run(cfg)
    torch.set_num_threads(cfg.torch_threads)

    # --- env, agent --------------------------------------------------------------------------------------
    env_kwargs = full["env_kwargs"]
    venv = make_env(env_kwargs, spec.n_envs, spec.gamma, spec.norm_reward)
    tb = os.path.join(run_dir, "tb")
    if manifest is None:
        model = make_agent(spec, venv, seed=cfg.seed, tensorboard_log=tb, verbose=cfg.verbose)
    else:
        venv = VecNormalize.load(manifest["vecnormalize"], venv.venv)
        model = ALGO_CLASSES[spec.algo].load(manifest["model"], env=venv, device="cpu", tensorboard_log=tb,
                                             verbose=cfg.verbose)

    # --- callbacks: wall clock, progress, held-out validation (best model), checkpoints ----------------
    scenarios, base, reference = validation(cfg, env_kwargs)
    wall = WallClock()
    evaluator = HeldoutEval(run_dir, env_kwargs, scenarios, base, reference, cfg.eval_freq, wall, on_eval)
    checkpoint = Checkpoint(run_dir, cfg.checkpoint_freq, {"wall": wall, "eval": evaluator},
                            lambda: env_generators(venv))
    progress = ProgressBar(cfg.timesteps, desc=name, disable=not cfg.progress)
    if manifest is not None:
        state = runs.read_state(manifest["state"])
        wall.load_state_dict(state["callbacks"]["wall"])
        evaluator.load_state_dict(state["callbacks"]["eval"], manifest["step"])
        restore_rng(state["rng"], env_generators(venv))  # PPO.load re-seeded everything from cfg.seed
        venv.venv._reset_seeds()  # ... and queued env seeds (SB3's VecEnv hook); keep the restored generators

    # --- learn -------------------------------------------------------------------------------------------
    remaining = cfg.timesteps - model.num_timesteps
    note = rollout_note(cfg.timesteps, int(model.num_timesteps),
                        spec.n_envs * (spec.n_steps if spec.algo == "ppo" else spec.train_freq))
    if note:
        print(f"note: {note}", file=sys.stderr)
    if remaining > 0:
        model.learn(total_timesteps=remaining, callback=CallbackList([wall, progress, evaluator, checkpoint]),
                    reset_num_timesteps=manifest is None, tb_log_name=spec.algo.upper(), progress_bar=False)
        checkpoint.init_callback(model)
        checkpoint.save()  # a finished run can be extended with --resume --timesteps LARGER

    # --- the best and the final model ----------------------------------------------------------------------
    summary = finish(cfg, model, venv, evaluator, base, reference, wall.seconds, wall.cpu_seconds)
    venv.close()
    return summary


def full_plant(cfg: Config):
    """The plant a run trains on, as its env settings record it (None = Table I)."""
    return cfg.full()["env_kwargs"].get("plant")


def finish(cfg: Config, model, venv, evaluator: HeldoutEval, base, reference, wall_s: float, cpu_s: float) -> dict:
    """Export the final and the best model; write and return ``summary.json``."""
    run_dir = cfg.run_dir()
    best = evaluator.history[[r["step"] for r in evaluator.history].index(evaluator.best_step)]
    export_model(model, venv, os.path.join(run_dir, "final"), cfg,
                 {"step": int(model.num_timesteps), "validation": evaluator.history[-1]})
    best_model = ALGO_CLASSES[cfg.spec().algo].load(os.path.join(evaluator.best_dir(), "model.zip"), device="cpu")
    best_vn = VecNormalize.load(os.path.join(evaluator.best_dir(), "vecnormalize.pkl"), venv.venv)
    export_model(best_model, best_vn, os.path.join(run_dir, "best"), cfg,
                 {"step": int(evaluator.best_step), "validation": best})
    summary = {"run_name": cfg.run_name(), "run_dir": run_dir, "agent": cfg.agent, "algo": cfg.spec().algo,
               "task": cfg.task, "n": cfg.n, "plant": plant_of(full_plant(cfg)).label,
               "seed": cfg.seed, "timesteps": int(model.num_timesteps), "wall_s": round(wall_s, 2),
               "cpu_s": round(cpu_s, 2),
               "best_step": evaluator.best_step, "best_validation": best,
               "best_is_untrained": evaluator.best_step == evaluator.history[0]["step"] == 0,
               "base_validation": relative_scores(base, base, reference, floors_of(cfg.full()["env_kwargs"])),
               "final_validation": evaluator.history[-1]}
    atomic_write_text(os.path.join(run_dir, "summary.json"), json.dumps(summary, indent=1) + "\n")
    return summary


def describe(summary: dict) -> str:
    """A few lines on a finished run: the best and the final policy's validation scores against the base law (both
    are exported, ``best/`` and ``final/``), whether the best is the untrained step-0 policy, the run folder."""
    def scores(row: dict) -> str:
        gate = f", FAILED the gate on {row['n_failed']} scenario(s)" if row["failed"] else ""
        classes = ", ".join(f"{c} x{fmt_num(row[f'rel_{c}'], '.3f')}"
                            for c in ("tracking", "disturbance", "effort", "chatter"))
        return f"validation figure {fmt_num(row['figure'], '.4f')}{gate}; {classes} of the base law"

    b, f = summary["best_validation"], summary["final_validation"]
    lines = [f"{summary['run_name']}: {summary['timesteps']} steps in {summary['wall_s']:.0f} s; base law "
             f"{fmt_num(summary['base_validation']['figure'], '.4f')} (lower is better)",
             f"  best  (step {summary['best_step']}): {scores(b)}",
             f"  final (step {f['step']}): {scores(f)}"]
    if summary.get("best_is_untrained"):
        what = ("a zero-initialised residual: the base law itself" if str(summary.get("agent", "")).startswith(
            "residual") else "the randomly initialised network")
        lines.append(f"  note: the best is the untrained step-0 policy ({what}); no later evaluation beat it, so best/ "
                     "holds no training")
    if "plant" in summary:
        lines.append(f"plant: {summary['plant']}")
    lines.append(f"run folder: {summary['run_dir']} (best/ and final/policy.json + .safetensors: safe weights)")
    return "\n".join(lines)


def main(argv=None, prog: str = "python -m ehss_gym.train.loop") -> int:
    """One training run from the command line; bad input prints a message naming the option and returns 2."""
    try:
        summary = train(config_from_args(build_parser().parse_args(argv)))
    except runs.RunError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    print(describe(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())


__all__ = ["CLIP_OBS", "make_env", "env_generators", "open_run", "export_model", "validation", "rollout_note",
           "train", "finish", "describe", "main"]
