"""``ehss evaluate``: scripted CLF laws (n = 2, 4, 6), a PID and learned policies on the same scenarios.

Every policy acts in the Gymnasium env ``EHSSTracking-v0`` (:class:`ehss_gym.envs.env.EHSSTrackingEnv`) through
SB3's ``predict(obs, state, episode_start, deterministic=True)``; every episode is pinned to a scenario
(``reset(options={"scenario": ...})``), so all policies see exactly the same references, friction
events, plants and sensor noise. Episodes run in worker processes (``spawn``) across the cores; the
split of episodes into jobs does not depend on the number of workers, so results are identical for
any ``--workers``.

**Suites** (per task; the physical episodes come from :mod:`ehss_gym.core.scenarios`):

- ``paper``: the paper's 20 s run (1 rad/s, 2 rad/s sine; 1.8 N*m friction from 8 s to 10 s).
- ``heldout``: ``K`` randomised episodes from :func:`ehss_gym.core.scenarios.heldout_scenarios` (seeds at
  ``HELDOUT_SEED_BASE + i`` and above, disjoint from every training seed).
- ``robustness``: two sweeps on episodes drawn from further held-out seeds (offset
  :data:`ROBUST_SEED_START`) with their noise removed and one friction event from
  :data:`SWEEP_WINDOW`: friction amplitude (plant = model) and model mismatch (beta, J, B, c_sm, P_s
  of the true plant each scaled by 1 +- level, signs drawn per episode; friction 1.8 N*m).

**Primary score** (lower is better; the score residual PPO must beat), per episode::

    score = 0.5 * RMSE / RMSE_ref + 0.5 * TV / TV_ref        (capped at SCORE_CAP; divergence = SCORE_CAP)

with TV the control total variation per second (chattering index) and ``_ref`` the reference law
:data:`REFERENCE_POLICY` (the CLF law with n = 2 at the env's defaults) on the same scenario. The
reference scores exactly 1 on every episode; 0.8 means 20 % better on the equal-weight mix of tracking
and chattering. See :func:`primary_score`.
"""

from __future__ import annotations

import csv
import glob
import io
import json
import math
import multiprocessing as mp
import os
import re
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from ehss_gym._version import __version__
from ehss_gym.envs.rollout import rollout as run_rollout

from . import stats as st

ENV_ID = "EHSSTracking-v0"
TASKS = ("velocity", "position")
SUITES = ("paper", "heldout", "robustness")
UNITS = {"velocity": "rad/s", "position": "rad"}
REFERENCE_POLICY = "clf-n2"
SCRIPTED_DEFAULT = ("clf-n2", "clf-n4", "clf-n6", "pid")
SCORE_CAP = 10.0  # [-] score of a diverged episode, and the most any episode can score
W_TRACK = 0.5  # weight of the RMSE ratio in the primary score
W_CHATTER = 0.5  # weight of the control-TV ratio
RMSE_FLOOR = 1e-12  # [output unit] guards a division by an exactly zero reference RMSE
TV_FLOOR = 1e-9  # [mA/s]
ROBUST_SEED_START = 1_000_000  # held-out seed offset of the robustness episodes (the heldout suite uses 0..K-1)
SWEEP_WINDOW = (0.8, 1.4)  # [s] friction event of the robustness sweeps (in 2 s episodes)
SWEEP_MISMATCH_FRICTION = 1.8  # [N*m] friction amplitude during the mismatch sweep (the paper's)
MISMATCH_PARAMS = ("beta", "J", "B", "c_sm", "P_s")
DEFAULT_OUT = os.path.join("reports", "comparison")

# (key, label, unit ("U" = output unit), definition) of every reported metric; keys of metrics.summarize_acc
METRICS = (
    ("rmse", "RMSE", "U", "sqrt(mean e^2) over all control steps, e = y - y_d"),
    ("rmse_nominal", "RMSE outside friction", "U", "the same over the steps with no friction event active"),
    ("iae", "IAE", "U*s", "sum |e| h over the control steps (h the control period)"),
    ("itae", "ITAE", "U*s^2", "sum t |e| h"),
    ("max_abs_e", "max |e|", "U", "largest |e| of the episode"),
    ("max_abs_e_friction", "max |e| in friction", "U", "largest |e| while a friction event is active"),
    ("recovery_on", "recovery on", "s",
     "time from the first friction switch-on until |e| enters and stays in 2x the largest |e| of the second "
     "before it (error sampled once per agent step); inf = never"),
    ("recovery_off", "recovery off", "s", "the same after that event switches off"),
    ("tv_u_rate", "control TV", "mA/s",
     "chattering index: sum |u_k - u_{k-1}| of the applied current over the control steps, per second"),
    ("rms_u", "RMS current", "mA", "sqrt(mean u^2) of the applied current"),
    ("peak_u_applied", "peak current", "mA", "largest |u| applied (after the current limit)"),
    ("saturation", "saturation", "-", "share of control steps on which the current limit clipped the command"),
    ("v_decrease", "V decrease", "-", "share of control steps on which the CLF value V = (s/sigma)^n/n fell"),
    ("diverged", "divergence rate", "-",
     "share of episodes stopped by a non-finite value, |x2| > omega_max or |x3| > 1.5 P_s"),
)
METRIC_KEYS = tuple(m[0] for m in METRICS)


class PolicyError(ValueError):
    """A policy specification that cannot be evaluated (unknown name, missing file, shapes that do not fit)."""


# ---------------------------------------------------------------------------------------------------
# Configuration


@dataclass(frozen=True)
class EvalConfig:
    """Sizes and seeds of an evaluation.

    Attributes:
        suites: any of "paper", "heldout", "robustness".
        tasks: any of "velocity", "position".
        heldout_episodes: randomised held-out episodes per task (K).
        episode_seconds: duration of held-out and robustness episodes [s].
        paper_seconds: duration of the paper run [s] (the paper: 20).
        friction_levels: friction amplitudes of the sweep [N*m].
        mismatch_levels: relative plant-parameter deviations of the mismatch sweep (0.2 = +-20 %).
        sweep_episodes: episodes per sweep level (M).
        n_boot: bootstrap replicates.
        seed: bootstrap seed.
        chunk: episodes per job (one job = one policy run on up to ``chunk`` episodes of one suite/task).
    """

    suites: tuple = SUITES
    tasks: tuple = TASKS
    heldout_episodes: int = 48
    episode_seconds: float = 2.0
    paper_seconds: float = 20.0
    friction_levels: tuple = (0.0, 0.9, 1.8, 2.7, 3.6)
    mismatch_levels: tuple = (0.0, 0.05, 0.1, 0.15, 0.2)
    sweep_episodes: int = 5
    n_boot: int = 2000
    seed: int = 0
    chunk: int = 24

    @classmethod
    def quick(cls, **changes) -> EvalConfig:
        """The CI form: 8 held-out episodes, one episode per sweep level, the paper run cut at 12 s (friction
        8-10 s and 2 s after it), fewer bootstrap replicates."""
        base = cls(heldout_episodes=8, paper_seconds=12.0, friction_levels=(0.0, 1.8, 3.6), mismatch_levels=(0.0, 0.2),
                   sweep_episodes=1, n_boot=1000)
        return replace(base, **changes)

    def __post_init__(self):
        bad = [s for s in self.suites if s not in SUITES]
        if bad or not self.suites:
            raise ValueError(f"suites must be a non-empty subset of {list(SUITES)}, got {list(self.suites)}")
        bad = [t for t in self.tasks if t not in TASKS]
        if bad or not self.tasks:
            raise ValueError(f"tasks must be a non-empty subset of {list(TASKS)}, got {list(self.tasks)}")
        for name in ("heldout_episodes", "sweep_episodes", "chunk"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {v!r}")
        for name in ("episode_seconds", "paper_seconds"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise ValueError(f"{name} must be a finite number > 0 (s), got {v!r}")
        if any(not math.isfinite(a) or a < 0 for a in self.friction_levels) or not self.friction_levels:
            raise ValueError(f"friction_levels must be finite amplitudes >= 0 (N*m), got {self.friction_levels}")
        if any(not math.isfinite(m) or not 0 <= m < 1 for m in self.mismatch_levels) or not self.mismatch_levels:
            raise ValueError(f"mismatch_levels must be in [0, 1), got {self.mismatch_levels}")
        if self.episode_seconds <= SWEEP_WINDOW[1] and "robustness" in self.suites:
            raise ValueError(f"episode_seconds must be > {SWEEP_WINDOW[1]} s for the robustness sweeps, got "
                             f"{self.episode_seconds}")


# ---------------------------------------------------------------------------------------------------
# Policies


@dataclass
class PolicySpec:
    """A policy to evaluate, with one entry in ``runs`` per training seed.

    Attributes:
        name: label in the report (unique).
        kind: "clf", "pid", "residual-ppo", "ppo-direct" or "object".
        runs: per training seed, what :func:`load_run` loads: a model path (str) or an object with
            ``predict`` (scripted policies: a dict describing them).
        env_kwargs: keyword arguments of the env the policy acts in (without ``task`` for scripted
            policies, which run on every task).
        tasks: tasks it runs on.
        source: human-readable origin (for the report).
    """

    name: str
    kind: str
    runs: list
    env_kwargs: dict
    tasks: tuple = TASKS
    source: str = ""

    @property
    def learned(self) -> bool:
        return self.kind in ("residual-ppo", "ppo-direct", "object")

    def env_kwargs_for(self, task: str) -> dict:
        kw = dict(self.env_kwargs)
        kw["task"] = task
        return kw


_CLF_RE = re.compile(r"^clf-n(\d+)$")
_SEED_RE = re.compile(r"^(.*?)[-_](?:seed|s)(\d+)$")


def _valid_forms() -> str:
    from ehss_gym.agents.safeweights import shipped_models

    names = sorted(shipped_models())
    shipped = ", ".join(names) if names else "none shipped yet"
    return ("clf-n<even n >= 2> (e.g. clf-n2, clf-n4, clf-n6), pid, residual-ppo:PATH, ppo-direct:PATH "
            "(PATH = an SB3 .zip, a safe-weights stem PATH with PATH.safetensors + PATH.json, or a glob "
            f"matching several training seeds), or a shipped model name ({shipped})")


def scripted_spec(name: str, label: str | None = None, env_overrides: dict | None = None,
                  gains: dict | None = None) -> PolicySpec:
    """``clf-n<n>`` or ``pid`` as a :class:`PolicySpec` (runs on both tasks).

    Args:
        name: "clf-n<even n>" or "pid".
        label: report name (default ``name``); needed when ``env_overrides`` change the law.
        env_overrides: env settings changed from the defaults (e.g. ``{"sigma": 1.0}``: the paper's scale).
        gains: PID only: task -> (kp, ki, kd) instead of the tuned gains.
    """
    over = dict(env_overrides or {})
    m = _CLF_RE.match(name)
    if m:
        n = int(m.group(1))
        if n < 2 or n % 2:
            raise PolicyError(f"unknown policy {name!r}: the CLF power factor must be an even integer >= 2 "
                              f"(clf-n2, clf-n4, clf-n6, ...)")
        src = f"scripted Sontag/CLF law, n = {n}" + (f", {over}" if over else "")
        return PolicySpec(name=label or name, kind="clf", runs=[{"kind": "clf", "n": n}],
                          env_kwargs={"n": n, "mode": "residual", **over}, source=src)
    if name == "pid":
        run = {"kind": "pid"}
        if gains:
            run["gains"] = {t: tuple(float(g) for g in v) for t, v in gains.items()}
        src = ("scripted PID (ehss_gym.controllers)" + (f", {over}" if over else "")
               + (f", gains {gains}" if gains else ""))
        return PolicySpec(name=label or "pid", kind="pid", runs=[run], env_kwargs={"mode": "direct", **over},
                          source=src)
    raise PolicyError(f"unknown policy {name!r}; valid: {_valid_forms()}")


def _sidecar_env_kwargs(zip_path: str) -> dict | None:
    """env_kwargs recorded next to an SB3 .zip (``STEM.json`` or the run folder's config.json), if any."""
    stem = zip_path[:-4]
    folder = os.path.dirname(os.path.abspath(zip_path))
    for cand in (stem + ".json", os.path.join(folder, "config.json"), os.path.join(os.path.dirname(folder),
                                                                                    "config.json")):
        if os.path.isfile(cand):
            try:
                with open(cand, encoding="utf-8") as f:
                    d = json.load(f)
            except (OSError, ValueError):
                continue
            if isinstance(d, dict) and isinstance(d.get("env_kwargs"), dict):
                return dict(d["env_kwargs"])
    return None


def _model_files(pattern: str, spec_text: str) -> list[str]:
    """The model paths a PATH (or glob) names; PolicyError if none exists.

    A safe-weights stem is preferred over an SB3 .zip in the same folder (a training run keeps both).
    """
    has_glob = any(c in pattern for c in "*?[")
    if has_glob:
        cands = sorted(set(glob.glob(pattern)) | set(glob.glob(pattern + ".json")) | set(glob.glob(pattern + ".zip")))
    else:
        cands = [pattern]
    out = []
    for p in cands:
        if p.endswith(".zip"):
            if os.path.isfile(p):
                out.append(p)
            continue
        stem = p[:-5] if p.endswith(".json") else (p[:-12] if p.endswith(".safetensors") else p)
        if os.path.isfile(stem + ".json") and os.path.isfile(stem + ".safetensors"):
            if stem not in out:
                out.append(stem)
        elif os.path.isfile(stem + ".zip"):
            out.append(stem + ".zip")
    if has_glob:
        safe_dirs = {os.path.dirname(p) for p in out if not p.endswith(".zip")}
        out = [p for p in out if not (p.endswith(".zip") and os.path.dirname(p) in safe_dirs)]
    if not out:
        what = "no file matches the pattern" if has_glob else "file not found"
        raise PolicyError(f"policy {spec_text!r}: {what} {pattern!r}; PATH must be an SB3 .zip or a safe-weights "
                          "stem with PATH.safetensors + PATH.json")
    return sorted(dict.fromkeys(out))


def _run_env_kwargs(path: str, kind: str, spec_text: str) -> dict:
    """The env kwargs a model was trained with, checked against the spec's mode."""
    want_mode = "residual" if kind == "residual-ppo" else "direct"
    if path.endswith(".zip"):
        kw = _sidecar_env_kwargs(path) or {}
    else:
        from ehss_gym.agents.safeweights import load_policy

        pol = load_policy(path)
        if pol.env_id != ENV_ID:
            raise PolicyError(f"policy {spec_text!r}: model {path!r} was trained on {pol.env_id!r}, not {ENV_ID!r}")
        kw = dict(pol.env_kwargs)
    mode = kw.get("mode", "residual")
    if "mode" in kw and mode != want_mode:
        right = "residual-ppo" if mode == "residual" else "ppo-direct"
        raise PolicyError(f"policy {spec_text!r}: model {path!r} was trained with mode={mode!r}; name it "
                          f"{right}:{path} (residual-ppo = mode 'residual', ppo-direct = mode 'direct')")
    kw["mode"] = want_mode
    for k in ("scenario", "render_mode"):
        kw.pop(k, None)
    return kw


_GENERIC = ("policy", "model", "best_model", "final_model", "best", "final", "checkpoints")


def _path_label(path: str) -> str:
    """A readable name for a model path: its file stem, or the run folder for generic stems (policy, model)."""
    parts = os.path.normpath(os.path.abspath(path)).split(os.sep)
    stem = parts[-1].removesuffix(".zip")
    if stem not in _GENERIC:
        return stem
    for folder in reversed(parts[:-1]):
        if folder and folder not in _GENERIC:
            return folder
    return stem


def learned_spec(kind: str, pattern: str, spec_text: str | None = None, name: str | None = None) -> PolicySpec:
    """A learned policy from one model file or a glob of several training seeds."""
    spec_text = spec_text or f"{kind}:{pattern}"
    paths = _model_files(pattern, spec_text)
    kws = [_run_env_kwargs(p, kind, spec_text) for p in paths]
    first = kws[0]
    for p, kw in zip(paths[1:], kws[1:]):
        if kw != first:
            raise PolicyError(f"policy {spec_text!r}: the training seeds were trained with different env settings "
                              f"({paths[0]}: {first}; {p}: {kw}); evaluate them as separate policies")
    tasks = (first["task"],) if "task" in first else ("velocity",)
    if name is None:
        labels = [_path_label(p) for p in paths]
        zip_tag = " (sb3 zip)" if all(p.endswith(".zip") for p in paths) else ""
        if len(labels) == 1:
            name = f"{kind}:{labels[0]}{zip_tag}"
        else:
            common = os.path.commonprefix(labels).rstrip("-_")
            m = _SEED_RE.match(common) if common else None
            name = f"{kind}:{common or labels[0]}" if not m else f"{kind}:{m.group(1)}"
            name = re.sub(r"[-_](?:seed|s)$", "", name) + zip_tag
    return PolicySpec(name=name, kind=kind, runs=list(paths), env_kwargs=first, tasks=tasks,
                      source=", ".join(os.path.relpath(p) if not os.path.isabs(p) else p for p in paths))


def shipped_specs() -> list[PolicySpec]:
    """Every model in ``ehss_gym/models``, one spec per name with its ``-seed<k>`` files as training seeds."""
    from ehss_gym.agents.safeweights import load_policy, shipped_models

    groups: dict[str, list[str]] = {}
    for nm, path in shipped_models().items():
        m = _SEED_RE.match(nm)
        groups.setdefault(m.group(1) if m else nm, []).append(path)
    out = []
    for base, paths in sorted(groups.items()):
        mode = load_policy(paths[0]).env_kwargs.get("mode", "residual")
        kind = "residual-ppo" if mode == "residual" else "ppo-direct"
        pattern_spec = learned_spec(kind, paths[0], spec_text=base, name=base)
        if len(paths) > 1:
            kws = [_run_env_kwargs(p, kind, base) for p in paths]
            if any(kw != kws[0] for kw in kws):
                raise PolicyError(f"shipped model group {base!r}: seeds trained with different env settings")
            pattern_spec.runs = sorted(paths)
        pattern_spec.source = "shipped: " + ", ".join(os.path.basename(p) for p in pattern_spec.runs)
        out.append(pattern_spec)
    return out


def parse_policy(text: str) -> PolicySpec:
    """One ``--policies`` entry as a :class:`PolicySpec`; :class:`PolicyError` names what would fit."""
    text = text.strip()
    if not text:
        raise PolicyError(f"empty policy name; valid: {_valid_forms()}")
    if ":" in text:
        kind, _, path = text.partition(":")
        if kind not in ("residual-ppo", "ppo-direct"):
            raise PolicyError(f"unknown policy kind {kind!r} in {text!r}; valid: {_valid_forms()}")
        if not path:
            raise PolicyError(f"policy {text!r} needs a PATH after the colon; valid: {_valid_forms()}")
        return learned_spec(kind, path, spec_text=text)
    if _CLF_RE.match(text) or text == "pid":
        return scripted_spec(text)
    from ehss_gym.agents.safeweights import shipped_models

    shipped = {s.name: s for s in shipped_specs()} if shipped_models() else {}
    if text in shipped:
        return shipped[text]
    if text in shipped_models():  # one seed of a group, by its full name
        from ehss_gym.agents.safeweights import load_policy

        path = shipped_models()[text]
        mode = load_policy(path).env_kwargs.get("mode", "residual")
        return learned_spec("residual-ppo" if mode == "residual" else "ppo-direct", path, spec_text=text, name=text)
    raise PolicyError(f"unknown policy {text!r}; valid: {_valid_forms()}")


def object_spec(name: str, policy, env_kwargs: dict | None = None, runs: Sequence | None = None) -> PolicySpec:
    """Any object (or list of objects, one per training seed) with SB3's ``predict`` as a policy.

    Args:
        name: report label.
        policy: an object with ``predict``; ignored when ``runs`` is given.
        env_kwargs: env settings it acts in (default: ``policy.env_kwargs`` if present, else the env's
            defaults); ``task`` restricts it to one task.
        runs: several objects, one per training seed.
    """
    objs = list(runs) if runs is not None else [policy]
    for o in objs:
        if not callable(getattr(o, "predict", None)):
            raise PolicyError(f"policy {name!r}: {type(o).__name__} has no predict(obs, state, episode_start, "
                              "deterministic) method")
    kw = dict(env_kwargs if env_kwargs is not None else getattr(objs[0], "env_kwargs", None) or {})
    for k in ("scenario", "render_mode"):
        kw.pop(k, None)
    tasks = (kw["task"],) if "task" in kw else TASKS
    return PolicySpec(name=name, kind="object", runs=objs, env_kwargs=kw, tasks=tasks,
                      source=f"Python object {type(objs[0]).__name__}")


def default_specs() -> list[PolicySpec]:
    """Every shipped policy: the scripted CLF (n = 2, 4, 6) and PID, and the models in ehss_gym/models."""
    return [scripted_spec(n) for n in SCRIPTED_DEFAULT] + shipped_specs()


# --- loading (in the worker) -------------------------------------------------------------------------


class _Normalized:
    """An SB3 model plus VecNormalize observation statistics (for .zip models trained with VecNormalize)."""

    def __init__(self, model, mean, var, eps, clip):
        self.model = model
        self.observation_space = model.observation_space
        self.action_space = model.action_space
        self._mean, self._std, self._clip = mean, np.sqrt(var + eps), clip

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        obs = np.clip((np.asarray(observation) - self._mean) / self._std, -self._clip, self._clip).astype(np.float32)
        return self.model.predict(obs, state=state, episode_start=episode_start, deterministic=deterministic)


SB3_ALGOS = ("PPO", "A2C", "SAC", "TD3", "DDPG")


def _load_zip(path: str):
    """An SB3 model .zip (PPO, A2C, SAC, TD3 or DDPG), with a VecNormalize .pkl next to it if there is one."""
    import stable_baselines3 as sb3

    model, errors = None, []
    for algo in SB3_ALGOS:
        try:
            model = getattr(sb3, algo).load(path, device="cpu")
            break
        except Exception as exc:  # the file records its policy class, not its algorithm: try each in turn
            errors.append(f"{algo}: {type(exc).__name__}: {str(exc)[:120]}")
    if model is None:
        raise PolicyError(f"{path} is not a loadable stable-baselines3 model ({'; '.join(errors)})")
    stem = path[:-4]
    folder = os.path.dirname(os.path.abspath(path))
    for cand in (stem + "_vecnormalize.pkl", stem + ".vecnormalize.pkl", os.path.join(folder, "vecnormalize.pkl")):
        if os.path.isfile(cand):
            import pickle

            with open(cand, "rb") as f:  # SB3's own format; .zip users accept pickle (see safeweights)
                vn = pickle.load(f)
            if getattr(vn, "norm_obs", False):
                return _Normalized(model, vn.obs_rms.mean, vn.obs_rms.var, vn.epsilon, vn.clip_obs)
            break
    return model


def load_run(run, task: str, env_kwargs: dict):
    """The object with ``predict`` for one run of a spec (scripted descriptions are built for ``task``)."""
    if isinstance(run, dict):
        from ehss_gym.controllers import CLFPolicy, PIDPolicy
        from ehss_gym.envs import EnvConfig

        cfg = EnvConfig.from_kwargs({**env_kwargs, "task": task})
        if run["kind"] == "clf":
            return CLFPolicy(cfg)
        return PIDPolicy(cfg, gains=(run.get("gains") or {}).get(task))
    if isinstance(run, str):
        if run.endswith(".zip"):
            return _load_zip(run)
        from ehss_gym.agents.safeweights import load_policy

        return load_policy(run)
    return run


CONTROLLER_KEYS = ("fr", "sigma", "smoothing", "current_limit", "control_period", "substeps", "estimator_hz")


def controller_settings(env_kwargs: dict, task: str) -> dict:
    """The settings that shape the base law's closed loop (defaults resolved), for "same settings" checks."""
    from ehss_gym.envs import EnvConfig

    cfg = EnvConfig.from_kwargs({k: v for k, v in env_kwargs.items() if k != "mode"} | {"task": task})
    return {k: getattr(cfg, k) for k in CONTROLLER_KEYS}


def matched_clf_specs(specs: Sequence[PolicySpec], tasks: Sequence[str]) -> list[PolicySpec]:
    """CLF laws n = 2, 4, 6 at the controller settings of learned policies that differ from the defaults.

    A learned policy must be compared with the scripted laws *at the same settings*; when it was trained
    with, say, another sigma or current limit, these extra specs (``clf-n2@sigma=...``) provide them.
    """
    have = {s.name for s in specs}
    out = []
    for spec in specs:
        if not spec.learned:
            continue
        for task in spec.tasks:
            if task not in tasks:
                continue
            mine = controller_settings(spec.env_kwargs, task)
            default = controller_settings({}, task)
            diff = {k: v for k, v in mine.items() if v != default[k]}
            if not diff:
                continue
            tag = ",".join(f"{k}={'none' if v is None else format(v, 'g')}" for k, v in diff.items())
            for n in (2, 4, 6):
                label = f"clf-n{n}@{tag}"
                if label in have:
                    continue
                extra = scripted_spec(f"clf-n{n}", label=label, env_overrides=diff)
                extra.tasks = (task,)
                extra.source += f" (the settings of {spec.name})"
                out.append(extra)
                have.add(label)
    return out


def make_env(env_kwargs: dict):
    """The env a policy acts in (the class behind ``gym.make("EHSSTracking-v0")``, without wrappers)."""
    from ehss_gym.envs import EHSSTrackingEnv

    return EHSSTrackingEnv(**env_kwargs)


def check_fit(spec: PolicySpec, policy, task: str) -> None:
    """PolicyError unless the policy's observation/action shapes fit the env it will act in."""
    kw = spec.env_kwargs_for(task)
    try:
        env = make_env(kw)
    except ValueError as exc:
        raise PolicyError(f"policy {spec.name!r}: its env settings {kw} are not valid for {ENV_ID}: {exc}") from None
    want_obs = tuple(env.observation_space.shape)
    want_act = tuple(env.action_space.shape)
    obs_space = getattr(policy, "observation_space", None)
    act_space = getattr(policy, "action_space", None)
    got_obs = tuple(obs_space.shape) if obs_space is not None else None
    got_act = tuple(act_space.shape) if act_space is not None else None
    if got_act is None:  # a plain object: ask it
        try:
            a, _ = policy.predict(np.zeros((1,) + want_obs, dtype=np.float32), state=None,
                                  episode_start=np.ones(1, dtype=bool), deterministic=True)
            got_act = tuple(np.asarray(a).shape[1:])
        except Exception as exc:  # any failure of foreign code is reported with its name
            raise PolicyError(f"policy {spec.name!r}: predict() on a batch of observations of shape "
                              f"(1, {want_obs[0]}) failed ({type(exc).__name__}: {exc})") from None
    if (got_obs is not None and got_obs != want_obs) or got_act != want_act:
        fits = []
        for t in TASKS:
            try:
                e = make_env({**kw, "task": t})
                fits.append(f"task={t!r}: observation {tuple(e.observation_space.shape)}")
            except ValueError:
                pass
        raise PolicyError(
            f"policy {spec.name!r} does not fit {ENV_ID}(task={task!r}, mode={kw.get('mode', 'residual')!r}): it "
            f"expects observations of shape {got_obs} and gives actions of shape {got_act}, the env has "
            f"observation shape {want_obs} and action shape {want_act}. What fits: "
            f"{'; '.join(fits)}; action {want_act} in [-1, 1].")


# ---------------------------------------------------------------------------------------------------
# Suites: the physical episodes


@dataclass(frozen=True)
class Episode:
    """One pinned episode: its physical fields (:data:`ehss_gym.core.scenarios.PHYSICAL_FIELDS`) and labels."""

    suite: str
    task: str
    episode_id: str
    physical: dict = field(repr=False, hash=False, compare=False)
    sweep: str = ""
    level: float = math.nan
    scenario_seed: int = -1

    @property
    def t_end(self) -> float:
        return float(self.physical["t_end"])


def _physical(sc) -> dict:
    from ehss_gym.core.scenarios import PHYSICAL_FIELDS

    return {f: getattr(sc, f) for f in PHYSICAL_FIELDS}


def _template(task: str):
    from ehss_gym.envs import EnvConfig

    return EnvConfig.from_kwargs({"task": task}).template()


def build_episodes(cfg: EvalConfig) -> list[Episode]:
    """Every episode of the configured suites and tasks, in a fixed order."""
    from ehss_gym.core.params import PlantParams
    from ehss_gym.core.scenarios import HELDOUT_SEED_BASE, heldout_scenarios, paper_scenario

    out: list[Episode] = []
    nominal = PlantParams()
    for task in cfg.tasks:
        tmpl = _template(task)
        if "paper" in cfg.suites:
            out.append(Episode("paper", task, "paper", _physical(paper_scenario(tmpl, cfg.paper_seconds))))
        if "heldout" in cfg.suites:
            for i, sc in enumerate(heldout_scenarios(cfg.heldout_episodes, tmpl, cfg.episode_seconds)):
                out.append(Episode("heldout", task, f"heldout-{i}", _physical(sc), scenario_seed=HELDOUT_SEED_BASE + i))
        if "robustness" in cfg.suites:
            base = heldout_scenarios(cfg.sweep_episodes, tmpl, cfg.episode_seconds, start=ROBUST_SEED_START)
            t0, t1 = SWEEP_WINDOW
            for amp in cfg.friction_levels:
                for i, sc in enumerate(base):
                    sc2 = sc.replace(friction=((float(amp), t0, t1),) if amp > 0 else (), plant=nominal, model=nominal,
                                     noise_std=(0.0, 0.0, 0.0, 0.0))
                    out.append(Episode("robustness", task, f"friction={amp:g}#{i}", _physical(sc2), "friction",
                                       float(amp), HELDOUT_SEED_BASE + ROBUST_SEED_START + i))
            for lvl in cfg.mismatch_levels:
                for i, sc in enumerate(base):
                    signs = np.random.default_rng(ROBUST_SEED_START + i).choice([-1.0, 1.0], len(MISMATCH_PARAMS))
                    plant = nominal.scaled(**{p: 1.0 + float(lvl) * s for p, s in zip(MISMATCH_PARAMS, signs)})
                    sc2 = sc.replace(friction=((SWEEP_MISMATCH_FRICTION, t0, t1),), plant=plant, model=nominal,
                                     noise_std=(0.0, 0.0, 0.0, 0.0))
                    out.append(Episode("robustness", task, f"mismatch={lvl:g}#{i}", _physical(sc2), "mismatch",
                                       float(lvl), HELDOUT_SEED_BASE + ROBUST_SEED_START + i))
    return out


# ---------------------------------------------------------------------------------------------------
# Running episodes


@dataclass
class Job:
    """One policy run on a list of episodes of one suite and task (what a worker does)."""

    job_id: int
    spec: PolicySpec
    run_index: int
    task: str
    episodes: list
    trace: bool = False

    @property
    def cost(self) -> float:
        return sum(ep.t_end for ep in self.episodes)


_WORKER_CACHE: dict = {}
_IN_WORKER = False


def _worker_init() -> None:
    """One thread per worker process: the parallelism is across processes."""
    global _IN_WORKER
    _IN_WORKER = True
    try:
        import numba

        numba.set_num_threads(1)
    except Exception:  # numba's thread layer may refuse in exotic set-ups; one thread is only a preference
        pass


def _get_policy(spec: PolicySpec, run_index: int, task: str):
    key = (spec.name, run_index, task)
    if key not in _WORKER_CACHE:
        _WORKER_CACHE[key] = load_run(spec.runs[run_index], task, spec.env_kwargs_for(task))
        if _IN_WORKER and "torch" in sys.modules:  # a learned policy: one torch thread per worker process
            sys.modules["torch"].set_num_threads(1)
    return _WORKER_CACHE[key]


def rollout(policy, env_kwargs: dict, episodes: Sequence[Episode], trace: bool = False, name: str = "policy"):
    """Run ``policy`` on pinned episodes side by side: :func:`ehss_gym.envs.rollout.rollout`, the one loop.

    Returns:
        (list of per-episode dicts: the core metrics plus ``n_clipped`` and ``agent_steps``,
        list of trace dicts or None). A trace holds, per agent step, t [s], y_ref and y [output unit],
        e [output unit], u [mA] (applied) and friction [N*m].
    """
    res = run_rollout(policy, env_kwargs, [ep.physical for ep in episodes], trace=trace, name=name)
    return [r.metrics for r in res], ([r.trace for r in res] if trace else None)


def _run_job(job: Job):
    policy = _get_policy(job.spec, job.run_index, job.task)
    res, traces = rollout(policy, job.spec.env_kwargs_for(job.task), job.episodes, job.trace, job.spec.name)
    return job.job_id, res, traces


def make_jobs(specs: Sequence[PolicySpec], episodes: Sequence[Episode], chunk: int) -> list[Job]:
    """Split the work into jobs: (policy, run, task, suite) groups cut into at most ``chunk`` episodes."""
    jobs: list[Job] = []
    for spec in specs:
        for r in range(len(spec.runs)):
            for task in TASKS:
                if task not in spec.tasks:
                    continue
                for suite in SUITES:
                    eps = [ep for ep in episodes if ep.task == task and ep.suite == suite]
                    if not eps:
                        continue
                    n_parts = -(-len(eps) // chunk)
                    for part in np.array_split(np.arange(len(eps)), n_parts):
                        jobs.append(Job(len(jobs), spec, r, task, [eps[i] for i in part], trace=suite == "paper"))
    return jobs


def default_workers() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)


def run_jobs(jobs: Sequence[Job], workers: int, progress: bool = True) -> dict:
    """Run jobs in ``workers`` spawned processes (in-process when 1); job_id -> (results, traces)."""
    from tqdm import tqdm

    total = sum(len(j.episodes) for j in jobs)
    bar = tqdm(total=total, unit="ep", desc="ehss evaluate", disable=not progress, file=sys.stderr)
    out = {}
    order = sorted(jobs, key=lambda j: -j.cost)  # longest first keeps the pool busy to the end
    if workers <= 1:
        for job in order:
            jid, res, tr = _run_job(job)
            out[jid] = (res, tr)
            bar.update(len(job.episodes))
    else:
        ctx = mp.get_context("spawn")
        with ctx.Pool(workers, initializer=_worker_init) as pool:
            for jid, res, tr in pool.imap_unordered(_run_job, order, chunksize=1):
                out[jid] = (res, tr)
                bar.update(len(jobs[jid].episodes))
    bar.close()
    return out


# ---------------------------------------------------------------------------------------------------
# Scores and statistics


def primary_score(rmse: float, tv_rate: float, rmse_ref: float, tv_ref: float, diverged: bool) -> float:
    """The primary score of one episode (lower is better; the reference law scores 1).

    ``0.5 * RMSE / RMSE_ref + 0.5 * TV / TV_ref``, capped at :data:`SCORE_CAP`; a diverged episode
    scores :data:`SCORE_CAP`. RMSE in the output unit, TV the control total variation per second [mA/s];
    ``_ref`` are those of :data:`REFERENCE_POLICY` on the same scenario.
    """
    if diverged or not (math.isfinite(rmse) and math.isfinite(tv_rate)):
        return SCORE_CAP
    s = W_TRACK * rmse / max(rmse_ref, RMSE_FLOOR) + W_CHATTER * tv_rate / max(tv_ref, TV_FLOOR)
    return float(min(s, SCORE_CAP))


@dataclass
class Results:
    """Everything an evaluation produced."""

    cfg: EvalConfig
    specs: list
    episodes: list
    rows: list  # per-episode records (dicts)
    traces: dict  # (policy, run, task) -> paper trace
    summary: list  # per (suite, task, policy) dicts
    comparisons: list  # learned vs best CLF / base law
    wall_time: float = math.nan
    timings: dict = field(default_factory=dict)  # phase -> wall time [s]: setup, episodes, statistics, report
    workers: int = 1
    command: str = "ehss evaluate"
    notes: list = field(default_factory=list)


def _score_rows(rows: list, episodes: Sequence[Episode]) -> None:
    """Add ``score`` to every row, normalised by the reference law on the same episode."""
    ref = {}
    for r in rows:
        if r["policy"] == REFERENCE_POLICY:
            ref[(r["suite"], r["task"], r["episode"])] = r
    valid = {}
    for (suite, task, _), r in ref.items():
        if not r["diverged"]:
            valid.setdefault((suite, task), []).append((r["rmse"], r["tv_u_rate"]))
    for r in rows:
        k = (r["suite"], r["task"], r["episode"])
        rr = ref.get(k)
        if rr is None:
            raise RuntimeError(f"no {REFERENCE_POLICY} result for {k}; the reference law must be evaluated")
        if rr["diverged"]:  # fall back on the suite median of the reference
            pool = valid.get((r["suite"], r["task"]))
            rm, tv = (np.median([p[0] for p in pool]), np.median([p[1] for p in pool])) if pool else (1.0, 1.0)
            r["score_normaliser"] = "suite median (reference diverged)"
        else:
            rm, tv = rr["rmse"], rr["tv_u_rate"]
            r["score_normaliser"] = "same episode"
        r["score"] = primary_score(r["rmse"], r["tv_u_rate"], rm, tv, r["diverged"])


def _matrix(rows: list, policy: str, suite: str, task: str, key: str = "score", episodes: list | None = None):
    """(runs, episodes) matrix of ``key`` in the given episode order."""
    sel = [r for r in rows if r["policy"] == policy and r["suite"] == suite and r["task"] == task]
    if not sel:
        return None, []
    eps = episodes or sorted({r["episode"] for r in sel}, key=lambda e: next(
        i for i, r in enumerate(sel) if r["episode"] == e))
    runs = sorted({r["run"] for r in sel})
    idx = {(r["run"], r["episode"]): r for r in sel}
    m = np.array([[float(idx[(ru, e)][key]) for e in eps] for ru in runs])
    return m, eps


def _scores_against(rows: list, policy: str, suite: str, task: str, episodes: list, ref: str) -> np.ndarray:
    """(runs, episodes) primary scores of ``policy`` normalised by the law ``ref`` on the same episodes (the
    suite median of ``ref`` where ``ref`` diverged), instead of by :data:`REFERENCE_POLICY`."""
    ref_rm = _matrix(rows, ref, suite, task, "rmse", episodes)[0][0]
    ref_tv = _matrix(rows, ref, suite, task, "tv_u_rate", episodes)[0][0]
    ref_div = _matrix(rows, ref, suite, task, "diverged", episodes)[0][0].astype(bool)
    if ref_div.any():
        ok = ~ref_div
        ref_rm = np.where(ref_div, np.median(ref_rm[ok]) if ok.any() else 1.0, ref_rm)
        ref_tv = np.where(ref_div, np.median(ref_tv[ok]) if ok.any() else 1.0, ref_tv)
    rm = _matrix(rows, policy, suite, task, "rmse", episodes)[0]
    tv = _matrix(rows, policy, suite, task, "tv_u_rate", episodes)[0]
    div = _matrix(rows, policy, suite, task, "diverged", episodes)[0].astype(bool)
    return np.array([[primary_score(rm[i, j], tv[i, j], ref_rm[j], ref_tv[j], div[i, j]) for j in range(rm.shape[1])]
                     for i in range(rm.shape[0])])


def _finite_mean(v) -> float:
    v = np.asarray(v, dtype=np.float64)
    v = v[np.isfinite(v)]
    return float(v.mean()) if v.size else math.nan


def summarize(rows: list, specs: Sequence[PolicySpec], cfg: EvalConfig) -> tuple[list, list]:
    """Per (suite, task, policy): score statistics, PoI against the best CLF and mean metrics; comparisons."""
    summary = []
    comparisons = []
    names = [s.name for s in specs]
    for suite in SUITES:
        for task in TASKS:
            present = [n for n in names if any(r["policy"] == n and r["suite"] == suite and r["task"] == task
                                               for r in rows)]
            if not present:
                continue
            ref_m, eps = _matrix(rows, REFERENCE_POLICY, suite, task)
            mats = {n: _matrix(rows, n, suite, task, episodes=eps)[0] for n in present}
            clfs = [n for n in present if _CLF_RE.match(n)]
            best = min(clfs, key=lambda n: (mats[n].mean(), n)) if clfs else None
            block = []
            for k, n in enumerate(present):
                m = mats[n]
                s = st.summarize_scores(m, n_boot=cfg.n_boot, seed=cfg.seed + 101 * k)
                d = {"suite": suite, "task": task, "policy": n, "rank": 0, "n_runs": s["n_runs"],
                     "n_episodes": s["n_episodes"],
                     "score_mean": s["mean"], "score_mean_lo": s["mean_ci"][0], "score_mean_hi": s["mean_ci"][1],
                     "score_iqm": s["iqm"], "score_iqm_lo": s["iqm_ci"][0], "score_iqm_hi": s["iqm_ci"][1],
                     "score_median": s["median"]}
                if s["n_runs"] > 1:
                    d["score_mean_lo_seeds"], d["score_mean_hi_seeds"] = s["mean_ci_seeds"]
                    d["score_mean_lo_both"], d["score_mean_hi_both"] = s["mean_ci_both"]
                d["best_clf"] = best or ""
                if best is not None and n != best:
                    p, lo, hi = st.probability_of_improvement_ci(m, mats[best], n_boot=cfg.n_boot,
                                                                 seed=cfg.seed + 7 + k)
                    d["poi_vs_best_clf"], d["poi_lo"], d["poi_hi"] = p, lo, hi
                else:
                    d["poi_vs_best_clf"] = d["poi_lo"] = d["poi_hi"] = math.nan
                sel = [r for r in rows if r["policy"] == n and r["suite"] == suite and r["task"] == task]
                ok = [r for r in sel if not r["diverged"]]
                for key in METRIC_KEYS:
                    if key == "diverged":
                        d["divergence_rate"] = float(np.mean([r["diverged"] for r in sel]))
                    elif key.startswith("recovery"):
                        vals = [r[key] for r in ok if not math.isnan(r[key])]
                        d[key] = _finite_mean(vals)
                        d[key + "_never"] = int(sum(1 for v in vals if math.isinf(v)))
                    else:
                        d[key] = _finite_mean([r[key] for r in ok])
                block.append(d)
            order = sorted(block, key=lambda d: (d["score_mean"], d["policy"]))
            for rank, d in enumerate(order, 1):
                d["rank"] = rank
            summary += order
            # learned policies: relative improvement over the best CLF at the same settings, ratios to the base law
            for n in present:
                spec = next(s for s in specs if s.name == n)
                if not spec.learned:
                    continue
                mine = controller_settings(spec.env_kwargs, task)
                same = [s for s in specs if s.kind == "clf" and s.name in mats and int(s.env_kwargs["n"]) in (2, 4, 6)
                        and controller_settings(s.env_kwargs, task) == mine]
                if not same:
                    continue
                # Scores against the n = 2 law *at these settings* (the reference law itself when the settings
                # are the defaults): a same-settings comparison must not be weighted by a loop the policy does
                # not act in (a smoothed law's tiny TV on noise-free episodes, say).
                ref_same = next((s.name for s in same if int(s.env_kwargs["n"]) == 2), REFERENCE_POLICY)
                sm = {x: (mats[x] if ref_same == REFERENCE_POLICY else
                          _scores_against(rows, x, suite, task, eps, ref_same)) for x in [n] + [s.name for s in same]}
                best_same = min(same, key=lambda s: (sm[s.name].mean(), s.name))
                m = sm[n]
                imp, lo, hi = st.relative_improvement_ci(m, sm[best_same.name], n_boot=cfg.n_boot, seed=cfg.seed + 3)
                p, plo, phi = st.probability_of_improvement_ci(m, sm[best_same.name], n_boot=cfg.n_boot,
                                                               seed=cfg.seed + 5)
                c = {"suite": suite, "task": task, "policy": n, "n_runs": m.shape[0], "best_clf": best_same.name,
                     "score_reference": ref_same, "score_mean": float(m.mean()),
                     "best_clf_score_mean": float(sm[best_same.name].mean()),
                     "improvement": imp, "improvement_lo": lo, "improvement_hi": hi, "poi": p, "poi_lo": plo,
                     "poi_hi": phi}
                base = best_same.name
                if spec.env_kwargs.get("mode", "residual") == "residual":
                    nn = int(spec.env_kwargs.get("n", 2))
                    base = next((s.name for s in same if int(s.env_kwargs["n"]) == nn), best_same.name)
                c["base_law"] = base
                for key, label in (("rmse", "rmse_ratio"), ("tv_u_rate", "tv_ratio"),
                                   ("max_abs_e_friction", "friction_peak_ratio")):
                    a = _matrix(rows, n, suite, task, key, eps)[0]
                    b = _matrix(rows, base, suite, task, key, eps)[0]
                    good = np.isfinite(a).all(axis=0) & np.isfinite(b).all(axis=0)
                    c[label] = float(a[:, good].mean() / b[:, good].mean()) if good.any() else math.nan
                comparisons.append(c)
    return summary, comparisons


# ---------------------------------------------------------------------------------------------------
# The evaluation


def evaluate(specs: Sequence[PolicySpec] | None = None, cfg: EvalConfig | None = None, workers: int | None = None,
             progress: bool = True, command: str = "ehss evaluate") -> Results:
    """Evaluate policies on the configured suites (see the module docstring).

    Args:
        specs: policies (default: :func:`default_specs`). The reference law :data:`REFERENCE_POLICY` is
            added when missing (the score needs it).
        cfg: sizes and seeds (default :class:`EvalConfig`).
        workers: processes (default: the cores available); 1 runs in this process.
        progress: show a tqdm progress bar on stderr.
        command: the command line recorded in the report.

    Raises:
        PolicyError: a policy that cannot be loaded or whose shapes do not fit the env.
    """
    t_start = time.perf_counter()
    cfg = cfg or EvalConfig()
    specs = list(default_specs() if specs is None else specs)
    notes = []
    names = [s.name for s in specs]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise PolicyError(f"policy names must be unique, got {dup} more than once")
    if REFERENCE_POLICY not in names:
        specs.insert(0, scripted_spec(REFERENCE_POLICY))
        notes.append(f"{REFERENCE_POLICY} was added: the primary score is normalised by it.")
    matched = matched_clf_specs(specs, cfg.tasks)
    if matched:
        specs += matched
        notes.append("CLF laws at the controller settings of the learned policies were added (" +
                     ", ".join(s.name for s in matched) + ") so that each is compared with the laws at its settings.")
    for spec in specs:
        run_tasks = [t for t in spec.tasks if t in cfg.tasks]
        if not run_tasks:
            notes.append(f"{spec.name} acts on task {spec.tasks[0]!r} only, which is not evaluated; skipped.")
        for task in run_tasks:
            for r in range(len(spec.runs)):
                try:
                    pol = load_run(spec.runs[r], task, spec.env_kwargs_for(task))
                except ValueError as exc:  # PolicyError, SafeWeightsError, bad env settings
                    msg = str(exc)
                    raise PolicyError(msg if msg.startswith("policy ") else f"policy {spec.name!r}: {msg}") from None
                check_fit(spec, pol, task)
                if spec.kind == "pid":  # tuned once here, not again in every worker
                    spec.runs[r].setdefault("gains", {})[task] = (pol.kp, pol.ki, pol.kd)
    specs = [replace(s, tasks=tuple(t for t in s.tasks if t in cfg.tasks)) for s in specs]
    specs = [s for s in specs if s.tasks]
    episodes = build_episodes(cfg)
    jobs = make_jobs(specs, episodes, cfg.chunk)
    workers = default_workers() if workers is None else int(workers)
    workers = max(1, min(workers, len(jobs)))
    if workers > 1 and any(s.kind == "object" for s in specs):
        import pickle

        try:
            pickle.dumps([s for s in specs if s.kind == "object"])
        except Exception:  # unpicklable user objects cannot travel to worker processes
            workers = 1
            notes.append("a Python policy object could not be pickled; episodes ran in one process.")
    t0 = time.perf_counter()
    t_setup = t0 - t_start
    done = run_jobs(jobs, workers, progress)
    rows = []
    traces = {}
    for job in jobs:
        res, tr = done[job.job_id]
        for ep, m in zip(job.episodes, res):
            row = {"suite": ep.suite, "task": ep.task, "policy": job.spec.name, "run": job.run_index,
                   "episode": ep.episode_id, "sweep": ep.sweep, "level": ep.level, "scenario_seed": ep.scenario_seed,
                   "t_end": ep.t_end}
            row.update({k: m[k] for k in METRIC_KEYS})
            row.update({k: m[k] for k in ("rmse_nominal", "peak_u", "tv_u", "divergence_reason", "t_diverged",
                                          "n_clipped")})
            rows.append(row)
        if tr is not None:
            for ep, trace in zip(job.episodes, tr):
                traces[(job.spec.name, job.run_index, ep.task)] = trace
    t1 = time.perf_counter()
    _score_rows(rows, episodes)
    summary, comparisons = summarize(rows, specs, cfg)
    t2 = time.perf_counter()
    timings = {"setup": t_setup, "episodes": t1 - t0, "statistics": t2 - t1}
    return Results(cfg=cfg, specs=specs, episodes=episodes, rows=rows, traces=traces, summary=summary,
                   comparisons=comparisons, wall_time=t2 - t_start, timings=timings, workers=workers,
                   command=command, notes=notes)


# ---------------------------------------------------------------------------------------------------
# Output


def _fmt(x, digits: int = 3) -> str:
    if x is None or (isinstance(x, str) and not x):
        return "-"
    if isinstance(x, str):
        return x
    if isinstance(x, (bool, np.bool_)):
        return "yes" if x else "no"
    x = float(x)
    if math.isnan(x):
        return "-"
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    if x == 0:
        return "0"
    a = abs(x)
    if a >= 1e4 or a < 1e-3:
        return f"{x:.{digits - 1}e}"
    return f"{x:.{digits}g}"


def _md(text: str) -> str:
    """Escape the pipes of |e| inside a markdown table cell."""
    return str(text).replace("|", "\\|")


def _csv_text(rows: list, columns: Sequence[str]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(columns)
    for r in rows:
        out = []
        for c in columns:
            v = r.get(c, "")
            if isinstance(v, float):
                out.append(repr(v) if math.isfinite(v) else ("inf" if v == math.inf else ("-inf" if v == -math.inf
                                                                                           else "nan")))
            elif v is None:
                out.append("")
            else:
                out.append(str(v))
        w.writerow(out)
    return buf.getvalue()


EPISODE_COLUMNS = ("suite", "task", "policy", "run", "episode", "sweep", "level", "scenario_seed", "t_end", "score",
                   "score_normaliser") + tuple(k for k in METRIC_KEYS) + ("peak_u", "tv_u",
                                                                          "divergence_reason", "t_diverged",
                                                                          "n_clipped")


def _summary_columns(summary: list) -> list[str]:
    cols: list[str] = []
    for d in summary:
        for k in d:
            if k not in cols:
                cols.append(k)
    return cols


def write_report(res: Results, out: str) -> str:
    """Write REPORT.md, episodes.csv, summary.csv, comparisons.csv and figures/ under ``out``; returns REPORT.md.

    Every file is written atomically; REPORT.md last, so an interrupted run leaves the previous report.
    """
    from ehss_gym.core.util import atomic_write_text

    os.makedirs(os.path.join(out, "figures"), exist_ok=True)
    atomic_write_text(os.path.join(out, "episodes.csv"), _csv_text(res.rows, EPISODE_COLUMNS))
    atomic_write_text(os.path.join(out, "summary.csv"), _csv_text(res.summary, _summary_columns(res.summary)))
    if res.comparisons:
        atomic_write_text(os.path.join(out, "comparisons.csv"),
                          _csv_text(res.comparisons, _summary_columns(res.comparisons)))
    t0 = time.perf_counter()
    figs = make_figures(res, os.path.join(out, "figures"))
    res.timings["figures"] = time.perf_counter() - t0
    text = report_text(res, figs)
    path = os.path.join(out, "REPORT.md")
    atomic_write_text(path, text)
    return path


def _save(fig, path: str) -> None:
    from ehss_gym.core.util import atomic_write

    atomic_write(path, lambda f: fig.savefig(f, format="png", dpi=90))


def _footer(fig, res: Results) -> None:
    fig.text(0.01, 0.005, f"made by: {res.command}  (ehss-gym {_version()})", fontsize=7, color="gray")


def _finish(fig, res: Results, folder: str, name: str, bottom: float) -> str:
    """Footer, layout (``bottom`` left for the footer), atomic PNG write and close; returns the path relative
    to the report."""
    import matplotlib.pyplot as plt

    _footer(fig, res)
    fig.tight_layout(rect=(0, bottom, 1, 1))
    p = os.path.join(folder, name)
    _save(fig, p)
    plt.close(fig)
    return os.path.join("figures", name)


def _version() -> str:
    return __version__


def _colors(names: Sequence[str]) -> dict:
    import matplotlib

    cmap = matplotlib.colormaps["tab10"]
    return {n: cmap(i % 10) for i, n in enumerate(names)}


def make_figures(res: Results, folder: str) -> dict:
    """All figures; returns a dict kind -> list of (relative path, caption)."""
    from ehss_gym.reporting.plotting import plt

    figs: dict = {"bars": [], "traces": [], "robustness": [], "metrics": []}
    names = [s.name for s in res.specs]
    col = _colors(names)
    # score bars with CIs, one figure per suite
    for suite in SUITES:
        tasks = [t for t in TASKS if any(d["suite"] == suite and d["task"] == t for d in res.summary)]
        if not tasks:
            continue
        fig, axes = plt.subplots(1, len(tasks), figsize=(5.2 * len(tasks), 0.45 * len(names) + 2.2), squeeze=False)
        for ax, task in zip(axes[0], tasks):
            block = [d for d in res.summary if d["suite"] == suite and d["task"] == task]
            block.sort(key=lambda d: -d["rank"])
            y = np.arange(len(block))
            means = np.array([d["score_mean"] for d in block])
            lo = means - np.array([d["score_mean_lo"] for d in block])
            hi = np.array([d["score_mean_hi"] for d in block]) - means
            ax.barh(y, means, xerr=[lo, hi], color=[col[d["policy"]] for d in block], alpha=0.8, capsize=3,
                    label="mean, 95 % CI")
            ax.plot([d["score_iqm"] for d in block], y, "kD", ms=4, label="IQM")
            ax.axvline(1.0, color="gray", ls="--", lw=1)
            ax.set_yticks(y, [d["policy"] for d in block], fontsize=8)
            ax.set_xlabel(f"primary score (lower is better; {REFERENCE_POLICY} = 1)")
            if means.max() / max(means.min(), 1e-9) > 20:
                ax.set_xscale("log")
            n_ep = block[0]["n_episodes"]
            ax.set_title(f"{suite} suite, {task} ({n_ep} episode{'s' if n_ep > 1 else ''})", fontsize=9)
            ax.legend(fontsize=7, loc="lower right")
        figs["bars"].append((_finish(fig, res, folder, f"scores_{suite}.png", 0.03),
                             f"Primary score per policy on the {suite} suite: bars = mean with 95 % bootstrap CI, "
                             "diamonds = IQM."))
    # heldout metric bars
    for task in TASKS:
        block = [d for d in res.summary if d["suite"] == "heldout" and d["task"] == task]
        if not block:
            continue
        keys = (("rmse", f"RMSE [{UNITS[task]}]"), ("max_abs_e_friction", f"max |e| in friction [{UNITS[task]}]"),
                ("tv_u_rate", "control TV [mA/s]"))
        fig, axes = plt.subplots(1, 3, figsize=(14, 0.4 * len(block) + 2.2))
        block.sort(key=lambda d: -d["rank"])
        for ax, (key, label) in zip(axes, keys):
            vals, los, his = [], [], []
            for d in block:
                m, _ = _matrix(res.rows, d["policy"], "heldout", task, key)
                v = m[np.isfinite(m)]
                if v.size:
                    mean = float(v.mean())
                    lo, hi = st.bootstrap_ci(v, "mean", n_boot=res.cfg.n_boot, seed=res.cfg.seed)
                else:
                    mean, lo, hi = math.nan, math.nan, math.nan
                vals.append(mean)
                los.append(mean - lo)
                his.append(hi - mean)
            y = np.arange(len(block))
            ax.barh(y, vals, xerr=[los, his], color=[col[d["policy"]] for d in block], alpha=0.8, capsize=3)
            ax.set_yticks(y, [d["policy"] for d in block], fontsize=8)
            ax.set_xlabel(label)
            fin = [v for v in vals if math.isfinite(v) and v > 0]
            if fin and max(fin) / min(fin) > 30:
                ax.set_xscale("log")
            else:
                ax.ticklabel_format(axis="x", style="sci", scilimits=(-2, 3))
        fig.suptitle(f"Held-out suite, {task}: mean over episodes (non-diverged) with 95 % bootstrap CI", fontsize=9)
        figs["metrics"].append((_finish(fig, res, folder, f"metrics_heldout_{task}.png", 0.03),
                                f"Held-out suite, {task}: RMSE, peak error in friction windows and control TV."))
    # paper traces
    for task in TASKS:
        tr = {n: res.traces[(n, 0, task)] for n in names if (n, 0, task) in res.traces}
        if not tr:
            continue
        unit = UNITS[task]
        ep = next(e for e in res.episodes if e.suite == "paper" and e.task == task)
        fr = [ev for ev in ep.physical["friction"] if ev[0] > 0]
        t_on = fr[0][1] if fr else 0.0
        zoom = (max(0.0, t_on - 0.3), t_on + 2.6) if fr else (0.0, ep.t_end)
        fig, ax = plt.subplots(4, 1, figsize=(10, 11))
        first = next(iter(tr.values()))
        ax[0].plot(first["t"], first["y_ref"], "k--", lw=1.2, label="reference $y_d$")
        for n, d in tr.items():
            ax[0].plot(d["t"], d["y"], lw=0.8, color=col[n], label=n)
            ax[1].plot(d["t"], d["e"], lw=0.7, color=col[n], label=n)
            sel = (d["t"] >= zoom[0]) & (d["t"] <= zoom[1])
            ax[2].plot(d["t"][sel], d["e"][sel], lw=0.8, color=col[n], label=n)
            ax[3].plot(d["t"][sel], d["u"][sel], lw=0.6, color=col[n], label=n)
        ax[0].set_ylabel(f"output [{unit}]")
        ax[1].set_ylabel(f"error e [{unit}]")
        ax[2].set_ylabel(f"e [{unit}] (zoom)")
        ax[3].set_ylabel("applied u [mA] (zoom)")
        ax[3].set_xlabel("time [s]")
        for a in ax[2:]:
            for ev in fr:
                a.axvspan(ev[1], ev[2], color="orange", alpha=0.12)
        ax[1].axhline(0, color="gray", lw=0.5)
        ax[0].legend(fontsize=7, ncol=3, loc="upper right")
        fig.suptitle(f"Paper scenario, {task} task: every policy overlaid (first training seed); friction "
                     f"shaded", fontsize=9)
        figs["traces"].append((_finish(fig, res, folder, f"paper_traces_{task}.png", 0.02),
                               f"Paper scenario, {task}: output, error (full and zoomed on the friction event) "
                               "and applied current of every policy (sampled once per agent step)."))
    # robustness curves
    for task in TASKS:
        rr = [r for r in res.rows if r["suite"] == "robustness" and r["task"] == task]
        if not rr:
            continue
        u = UNITS[task]
        panels = (("friction", "max_abs_e_friction", "friction amplitude [N m]", f"max |e| in friction [{u}]"),
                  ("friction", "rmse", "friction amplitude [N m]", f"RMSE [{UNITS[task]}]"),
                  ("mismatch", "rmse", "plant-parameter mismatch [+-]", f"RMSE [{UNITS[task]}]"),
                  ("mismatch", "tv_u_rate", "plant-parameter mismatch [+-]", "control TV [mA/s]"))
        fig, axes = plt.subplots(2, 2, figsize=(11, 8))
        for ax, (sweep, key, xl, yl) in zip(axes.ravel(), panels):
            for n in names:
                pr = [r for r in rr if r["policy"] == n and r["sweep"] == sweep]
                if not pr:
                    continue
                levels = sorted({r["level"] for r in pr})
                xs, ms, los, his = [], [], [], []
                for lv in levels:
                    v = np.array([r[key] for r in pr if r["level"] == lv and not r["diverged"]], dtype=float)
                    v = v[np.isfinite(v)]
                    if not v.size:
                        continue
                    xs.append(lv)
                    ms.append(v.mean())
                    if v.size > 1:
                        lo, hi = st.bootstrap_ci(v, "mean", n_boot=res.cfg.n_boot, seed=res.cfg.seed)
                    else:
                        lo = hi = float(v.mean())
                    los.append(lo)
                    his.append(hi)
                if xs:
                    ax.plot(xs, ms, "o-", color=col[n], lw=1.2, ms=3, label=n)
                    ax.fill_between(xs, los, his, color=col[n], alpha=0.15)
            ax.set_xlabel(xl)
            ax.set_ylabel(yl)
            ax.set_yscale("log")
        axes[0, 0].legend(fontsize=7)
        n_ep = res.cfg.sweep_episodes
        fig.suptitle(f"Robustness, {task}: mean over {n_ep} episodes per level (band: 95 % bootstrap CI; "
                     f"diverged episodes left out)", fontsize=9)
        figs["robustness"].append((_finish(fig, res, folder, f"robustness_{task}.png", 0.02),
                                   f"Robustness, {task}: error against friction amplitude and against model "
                                   "mismatch, per policy."))
    return figs


def _env_settings_lines(res: Results) -> list[str]:
    from ehss_gym.envs import EnvConfig

    out = ["| policy | kind | runs (training seeds) | tasks | env settings | source |", "|---|---|---|---|---|---|"]
    for s in res.specs:
        kw = ", ".join(f"{k}={v!r}" for k, v in sorted(s.env_kwargs.items())) or "defaults"
        out.append(f"| {s.name} | {s.kind} | {len(s.runs)} | {', '.join(s.tasks)} | {kw} | {s.source} |")
    out.append("")
    out.append("Env defaults the scripted laws use (the controller settings every pinned episode carries):")
    out.append("")
    out.append("| task | f_r [Hz] | sigma | smoothing | current limit [mA] | control period [s] | substeps | "
               "agent period | estimator [Hz] | residual scale [mA] |")
    out.append("|---|---|---|---|---|---|---|---|---|---|")
    for task in res.cfg.tasks:
        c = EnvConfig.from_kwargs({"task": task})
        out.append(f"| {task} | {c.fr:g} | {c.sigma:g} | {c.smoothing:g} | {c.current_limit} | {c.control_period:g} "
                   f"| {c.substeps} | {c.agent_period} | {c.estimator_hz:g} | {c.residual_scale:g} |")
    return out


def report_text(res: Results, figs: dict) -> str:
    """The markdown report."""
    cfg = res.cfg
    L_: list[str] = []
    L_ += ["# Policy comparison: Sontag/CLF laws, PID and learned policies", "",
           f"Generated by `{res.command}` (ehss-gym {_version()}); {len(res.rows)} episodes on {res.workers} worker "
           f"process(es); wall time {res.wall_time:.1f} s ("
           + ", ".join(f"{k} {v:.1f} s" for k, v in res.timings.items()) + "). Do not edit: rerun the command.", ""]
    learned = [s for s in res.specs if s.learned]
    if not learned:
        L_ += ["**No learned policy was evaluated**: no model was given and none is shipped in `ehss_gym/models/` "
               "yet. This report compares the scripted policies only; rerun the command when models exist.", ""]
    for n in res.notes:
        L_ += [f"- Note: {n}"]
    if res.notes:
        L_ += [""]
    L_ += ["## 1. Policies and settings", ""] + _env_settings_lines(res) + [""]
    L_ += ["## 2. Suites", "",
           f"All policies see the same pinned episodes (`reset(options={{'scenario': ...}})`). Suites run: "
           f"{', '.join(cfg.suites)}; tasks: {', '.join(cfg.tasks)}.", ""]
    if "paper" in cfg.suites:
        cut = "" if cfg.paper_seconds == 20.0 else " (cut short from the paper's 20 s)"
        L_ += [f"- **paper**: the paper's run, {cfg.paper_seconds:g} s{cut}, reference 1 (rad/s or rad) sine at "
               "2 rad/s, 1.8 N*m Coulomb friction from 8 s to 10 s, no mismatch, no noise. One deterministic "
               "episode per task, so it has no confidence interval over episodes."]
    if "heldout" in cfg.suites:
        L_ += [f"- **heldout**: {cfg.heldout_episodes} episodes per task of {cfg.episode_seconds:g} s from "
               "`ehss_gym.core.scenarios.heldout_scenarios` (scenario seeds HELDOUT_SEED_BASE + 0.."
               f"{cfg.heldout_episodes - 1}, HELDOUT_SEED_BASE = 2^62, never drawn in training): reference family "
               "(sine, step, chirp, multi-sine), amplitude, offset and frequency; 0-3 friction events up to 3.6 N*m "
               "(2x the paper's) at random times; true plant beta, J, B, c_sm, P_s within +-20 % of the "
               "controller's model; sensor noise on half of the episodes."]
    if "robustness" in cfg.suites:
        L_ += [f"- **robustness**: {cfg.sweep_episodes} references per level from held-out seeds "
               f"HELDOUT_SEED_BASE + {ROBUST_SEED_START} + i, {cfg.episode_seconds:g} s each, noise removed, one "
               f"friction event from {SWEEP_WINDOW[0]:g} s to {SWEEP_WINDOW[1]:g} s. Friction sweep: amplitude "
               f"{', '.join(f'{a:g}' for a in cfg.friction_levels)} N*m with plant = model. Mismatch sweep: true "
               f"plant beta, J, B, c_sm, P_s each scaled by 1 +- level (signs drawn per reference, fixed seed), "
               f"level {', '.join(f'{m:g}' for m in cfg.mismatch_levels)}, friction {SWEEP_MISMATCH_FRICTION:g} N*m."]
    L_ += [""]
    L_ += ["## 3. Primary score", "",
           "One number per episode combines tracking and chattering; **lower is better**. It is the score a "
           "learned policy (residual PPO) must beat:", "",
           "    score = 0.5 * RMSE / RMSE_ref + 0.5 * TV / TV_ref", "",
           f"RMSE is the tracking error's root mean square, TV the control total variation per second "
           f"(the chattering index, mA/s), and `_ref` are those of the reference law **{REFERENCE_POLICY}** (the "
           "Sontag/CLF law with n = 2 at the env's defaults) on the same scenario, so the score is comparable "
           "across scenarios of very different difficulty and the reference scores exactly 1 everywhere. "
           f"A diverged episode scores {SCORE_CAP:g}, and no episode scores more than {SCORE_CAP:g} (one blow-up "
           "cannot dominate a mean). If the reference itself diverged on an episode, that episode is normalised "
           "by the reference's median RMSE and TV over the suite. An improvement of 20 % is a score 20 % below "
           "the best CLF's.", ""]
    L_ += ["## 4. Metrics", "", "U is the output unit (rad/s velocity, rad position); h the control period. "
           "Metrics are accumulated at the full control rate; recovery times use the error sampled once per agent "
           "step. Means in the tables are over the non-diverged episodes; the divergence rate is over all.", "",
           "| metric | unit | definition |", "|---|---|---|"]
    for key, label, unit, text in METRICS:
        L_.append(f"| {_md(label)} (`{key}`) | {unit} | {_md(text)} |")
    L_ += ["", "## 5. Statistics", "",
           f"Per policy and suite: the mean and the interquartile mean (IQM, the mean of the middle 50 % of "
           f"episode scores) with 95 % percentile bootstrap confidence intervals ({cfg.n_boot} replicates, seeded) "
           "over episodes; for learned policies with several training seeds also over seeds and over both "
           "(two-way). The probability of improvement (PoI) against the best CLF (the clf-n* with the lowest mean "
           "score on that suite and task) follows rliable: per episode the Mann-Whitney statistic over pairs of "
           "runs (1 if the policy scores lower, 1/2 on a tie), averaged over episodes; its CI resamples episodes "
           "(paired) and runs within episodes. Implementation: `ehss_gym/stats.py` (tested against scipy).", ""]
    L_ += ["## 6. Results", ""]
    for suite in SUITES:
        for task in TASKS:
            block = [d for d in res.summary if d["suite"] == suite and d["task"] == task]
            if not block:
                continue
            unit = UNITS[task]
            L_ += [f"### {suite} suite, {task} task ({block[0]['n_episodes']} episode(s); best CLF: "
                   f"{block[0]['best_clf'] or '-'})", "",
                   "| rank | policy | score mean [95 % CI] | score IQM [95 % CI] | PoI vs best CLF [95 % CI] | "
                   f"RMSE [{unit}] | max abs e friction [{unit}] | TV [mA/s] | sat. | diverged |",
                   "|---|---|---|---|---|---|---|---|---|---|"]
            for d in block:
                ci = f"{_fmt(d['score_mean'])} [{_fmt(d['score_mean_lo'])}, {_fmt(d['score_mean_hi'])}]"
                if "score_mean_lo_seeds" in d:
                    ci += f"; seeds [{_fmt(d['score_mean_lo_seeds'])}, {_fmt(d['score_mean_hi_seeds'])}]"
                iq = f"{_fmt(d['score_iqm'])} [{_fmt(d['score_iqm_lo'])}, {_fmt(d['score_iqm_hi'])}]"
                poi = "-" if math.isnan(d["poi_vs_best_clf"]) else \
                    f"{d['poi_vs_best_clf']:.2f} [{d['poi_lo']:.2f}, {d['poi_hi']:.2f}]"
                L_.append(f"| {d['rank']} | {d['policy']} | {ci} | {iq} | {poi} | {_fmt(d['rmse'])} | "
                          f"{_fmt(d['max_abs_e_friction'])} | {_fmt(d['tv_u_rate'])} | {_fmt(d['saturation'])} | "
                          f"{d['divergence_rate']:.0%} |")
            L_ += [""]
    L_ += ["### All metrics (means over non-diverged episodes)", ""]
    hdr = ["suite", "task", "policy"] + [k for k in METRIC_KEYS if k != "diverged"] + ["divergence_rate"]
    L_ += ["| " + " | ".join(hdr) + " |", "|" + "---|" * len(hdr)]
    for d in res.summary:
        vals = [d["suite"], d["task"], d["policy"]]
        for k in hdr[3:]:
            v = _fmt(d.get(k))
            if k.startswith("recovery") and d.get(k + "_never"):
                v += f" ({d[k + '_never']} never)"
            vals.append(v)
        L_.append("| " + " | ".join(vals) + " |")
    L_ += [""]
    if figs.get("bars") or figs.get("metrics"):
        L_ += ["### Figures", ""]
        for p, cap in figs.get("bars", []) + figs.get("metrics", []):
            L_ += [f"![{cap}]({p})", "", f"*{cap}*", ""]
    if figs.get("traces"):
        L_ += ["## 7. Paper scenario traces", ""]
        for p, cap in figs["traces"]:
            L_ += [f"![{cap}]({p})", "", f"*{cap}*", ""]
    if figs.get("robustness"):
        L_ += ["## 8. Robustness", ""]
        for p, cap in figs["robustness"]:
            L_ += [f"![{cap}]({p})", "", f"*{cap}*", ""]
    L_ += ["## 9. Learned policies against the scripted laws", ""]
    if not res.comparisons:
        L_ += ["No learned policy was evaluated, so there is no verdict on residual PPO yet.", ""]
    else:
        L_ += ["Improvement = 1 - mean score / mean score of the best CLF n = 2/4/6 at the policy's controller "
               "settings (> 0: better), with both scores normalised by the CLF n = 2 *at those settings* (the "
               "score reference column; the ranking tables above use the reference law at the env's defaults for "
               "everyone), with a 95 % paired bootstrap CI over episodes and training seeds; PoI = "
               "probability of improvement over that law. Ratios are means over episodes against the policy's base "
               "law (the CLF with the same n and settings; for ppo-direct the best CLF): RMSE, control TV (issue 6: "
               "must not exceed 1) and peak |e| in friction windows (issue 6 target: <= 0.5).", "",
               "| suite | task | policy | seeds | score reference | best CLF (same settings) | improvement [95 % CI] | "
               "PoI [95 % CI] | base law | RMSE ratio | TV ratio | friction peak ratio |",
               "|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for c in res.comparisons:
            L_.append(f"| {c['suite']} | {c['task']} | {c['policy']} | {c['n_runs']} | {c['score_reference']} | "
                      f"{c['best_clf']} | "
                      f"{c['improvement']:+.1%} [{c['improvement_lo']:+.1%}, {c['improvement_hi']:+.1%}] | "
                      f"{c['poi']:.2f} [{c['poi_lo']:.2f}, {c['poi_hi']:.2f}] | "
                      f"{c['base_law']} | {_fmt(c.get('rmse_ratio'))} | {_fmt(c.get('tv_ratio'))} | "
                      f"{_fmt(c.get('friction_peak_ratio'))} |")
        L_ += [""]
    L_ += ["## Files", "",
           "- `episodes.csv`: one row per (policy, training seed, episode) with every metric and the score.",
           "- `summary.csv`: one row per (suite, task, policy) with the statistics and mean metrics.",
           "- `comparisons.csv`: learned policies against the best CLF and their base law (when any).",
           "- `figures/`: the figures above; each names the command that made it.", ""]
    return "\n".join(L_) + "\n"


# ---------------------------------------------------------------------------------------------------
# CLI


__all__ = ["EvalConfig", "PolicySpec", "PolicyError", "Episode", "Results", "evaluate", "write_report", "parse_policy",
           "scripted_spec", "learned_spec", "object_spec", "shipped_specs", "default_specs", "primary_score",
           "build_episodes", "rollout", "check_fit",
           "REFERENCE_POLICY", "SCORE_CAP", "METRICS"]
