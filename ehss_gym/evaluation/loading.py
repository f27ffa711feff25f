"""Loading: one run of a policy spec (a model path, a scripted-law description or an object) as an object with
SB3's ``predict``.

A run is what :attr:`ehss_gym.evaluation.specs.PolicySpec.runs` holds per training seed:

- a dict describing a scripted law (``{"kind": "clf", "n": n}`` or ``{"kind": "pid", "gains": ...}``), built
  for the task it acts on (cheap: no file is read);
- a model path: a safe-weights stem (``PATH.safetensors`` + ``PATH.json``, :mod:`ehss_gym.agents.safeweights`)
  or an SB3 ``.zip`` of any stable-baselines3 or sb3-contrib algorithm (read from the policy class it saved;
  with a VecNormalize ``.pkl`` next to it if there is one);
- any object with ``predict``, used as it is.

Safe-weights models are loaded once per process (:func:`load_safe` remembers them by the identity of their two
files, so spec parsing, the shape checks and the episodes share one load). Worker processes (local ones, or Ray
workers on other machines) get what :func:`portable` makes of a loaded run and rebuild it with :func:`restore`:
a safe-weights model as the bytes of its two files (no pickle; loaded through the safe-weights checks from a
private copy, so no worker needs the model's files), other objects as pickles; they read no model file unless an
object cannot be pickled, and then load it at most once each.
"""

from __future__ import annotations

import functools
import importlib
import json
import os
import pickle
import tempfile
import zipfile

import numpy as np
import yaml

from ehss_gym.agents.safeweights import SafePolicy, load_policy, model_paths
from ehss_gym.controllers import CLFPolicy, PIDPolicy
from ehss_gym.envs import ENV_ID, EHSSTrackingEnv, EnvConfig

ZOO_ARGS = "args.yml"  # rl-zoo3 saves its command line (env_kwargs included) in <run>/<env id>/args.yml
ZOO_CONFIG = "config.yml"  # ... and the hyperparameters it trained with (the config file's env_kwargs) beside it
# rl-zoo3's algorithm names (its --algo, recorded in args.yml) -> (package, class)
ZOO_ALGOS = {"a2c": ("stable_baselines3", "A2C"), "ddpg": ("stable_baselines3", "DDPG"),
             "dqn": ("stable_baselines3", "DQN"), "ppo": ("stable_baselines3", "PPO"),
             "sac": ("stable_baselines3", "SAC"), "td3": ("stable_baselines3", "TD3"), "ars": ("sb3_contrib", "ARS"),
             "qrdqn": ("sb3_contrib", "QRDQN"), "tqc": ("sb3_contrib", "TQC"), "trpo": ("sb3_contrib", "TRPO"),
             "ppo_lstm": ("sb3_contrib", "RecurrentPPO"), "crossq": ("sb3_contrib", "CrossQ")}


class PolicyError(ValueError):
    """A policy specification that cannot be evaluated (unknown name, missing file, shapes that do not fit)."""


class _Normalized:
    """An SB3 model plus VecNormalize observation statistics (for .zip models trained with VecNormalize)."""

    def __init__(self, model, mean, var, eps, clip):
        """Wrap ``model``.

        Args:
            model: the SB3 model.
            mean, var: VecNormalize's running observation mean and variance (per observation entry).
            eps: its epsilon (added to the variance).
            clip: its clip_obs (normalised observations are clipped to +-clip).
        """
        self.model = model
        self.observation_space = model.observation_space
        self.action_space = model.action_space
        self._mean, self._std, self._clip = mean, np.sqrt(var + eps), clip

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        """SB3's ``predict`` on normalised, clipped observations."""
        obs = np.clip((np.asarray(observation) - self._mean) / self._std, -self._clip, self._clip).astype(np.float32)
        return self.model.predict(obs, state=state, episode_start=episode_start, deterministic=deterministic)


def _file_identity(path: str) -> tuple:
    """(inode, size [B], mtime [ns]) of a file: a changed or replaced file has another identity."""
    st = os.stat(path)
    return st.st_ino, st.st_size, st.st_mtime_ns


@functools.lru_cache(maxsize=64)
def _load_safe_once(stem: str, identity: tuple) -> SafePolicy:
    """:func:`load_policy`, remembered per (absolute stem, identity of its two files)."""
    return load_policy(stem)


def load_safe(path: str) -> SafePolicy:
    """A safe-weights model, loaded from disk at most once per process while its files are unchanged.

    Args:
        path: the model stem (or either of its two files).

    Raises:
        SafeWeightsError: see :func:`ehss_gym.agents.safeweights.load_policy` (never remembered: a failed load is
            tried again).
    """
    st_path, js_path = model_paths(path)
    try:
        identity = (_file_identity(st_path), _file_identity(js_path))
    except OSError:  # a missing file: the loader names it
        return load_policy(path)
    return _load_safe_once(os.path.abspath(js_path[:-5]), identity)


class ZooLoader(yaml.SafeLoader):
    """yaml's safe loader plus the one tag rl-zoo3's ``args.yml`` uses (an OrderedDict, as [key, value] pairs)."""


ZooLoader.add_constructor("tag:yaml.org,2002:python/object/apply:collections.OrderedDict",
                          lambda loader, node: dict(loader.construct_sequence(node.value[0], deep=True)))


def zoo_params_dir(zip_path: str) -> str:
    """The folder where rl-zoo3 keeps the records of the run a model .zip belongs to: ``<run>/EHSSTracking-v0``."""
    return os.path.join(os.path.dirname(os.path.abspath(zip_path)), ENV_ID)


def read_zoo_record(path: str) -> dict | None:
    """An rl-zoo3 record (``args.yml`` or ``config.yml``) as a dict; None when the file is absent or unreadable."""
    try:
        with open(path, encoding="utf-8") as f:
            d = yaml.load(f, Loader=ZooLoader)
    except (OSError, yaml.YAMLError):
        return None
    return d if isinstance(d, dict) else None


def _load_vecnormalize(zip_path: str):
    """The VecNormalize statistics saved next to an SB3 .zip (or where rl-zoo3 keeps them), or None."""
    stem = zip_path[:-4]
    folder = os.path.dirname(os.path.abspath(zip_path))
    for cand in (stem + "_vecnormalize.pkl", stem + ".vecnormalize.pkl", os.path.join(folder, "vecnormalize.pkl"),
                 os.path.join(zoo_params_dir(zip_path), "vecnormalize.pkl")):
        if os.path.isfile(cand):
            with open(cand, "rb") as f:  # SB3's own format; .zip users accept pickle (see safeweights)
                return pickle.load(f)
    return None


# the sub-package of an algorithm (the module of its policy class) -> its class, where the name differs from upper case
_ALGO_CLASSES = {"ppo_recurrent": "RecurrentPPO", "ppo_mask": "MaskablePPO", "qrdqn": "QRDQN", "crossq": "CrossQ"}


def sb3_algorithm(path: str) -> tuple[str, str]:
    """(package, algorithm class) of an SB3 or sb3-contrib model .zip, read from its saved policy class.

    Raises:
        PolicyError: the file is not an SB3 model (not a zip, or no readable ``data`` entry naming the policy).
    """
    try:
        with zipfile.ZipFile(path) as z:
            data = json.loads(z.read("data"))
        module = data["policy_class"]["__module__"]
    except (OSError, zipfile.BadZipFile, KeyError, TypeError, ValueError) as exc:
        raise PolicyError(f"{path} is not a loadable stable-baselines3 model (a .zip whose 'data' entry names its "
                          f"policy class): {type(exc).__name__}: {exc}") from None
    parts = module.split(".")
    if len(parts) < 2 or parts[0] not in ("stable_baselines3", "sb3_contrib"):
        return _custom_policy_algorithm(path, module, data)
    sub = parts[1]
    if sub == "common" and parts[0] == "sb3_contrib":  # sb3_contrib.common.{recurrent,maskable}.policies
        return parts[0], "RecurrentPPO" if "recurrent" in parts else "MaskablePPO"
    if sub == "common":  # ActorCriticPolicy: PPO or A2C; PPO saves a clip range
        return parts[0], "PPO" if "clip_range" in data else "A2C"
    return parts[0], _ALGO_CLASSES.get(sub, sub.upper())


def _custom_policy_algorithm(path: str, module: str, data: dict) -> tuple[str, str]:
    """(package, algorithm class) of a model whose policy class is not SB3's own (e.g. the agents' policy,
    ``ehss_gym.agents.factory.AgentMlpPolicy``, which rl-zoo3 trains from the shipped config file): the algorithm
    rl-zoo3 recorded in its ``args.yml``, else PPO when the model saved PPO's clip range.

    Raises:
        PolicyError: neither says which algorithm saved the model.
    """
    args = read_zoo_record(os.path.join(zoo_params_dir(path), ZOO_ARGS)) or {}
    algo = str(args.get("algo", "")).lower()
    if algo in ZOO_ALGOS:
        return ZOO_ALGOS[algo]
    if "clip_range" in data:
        return "stable_baselines3", "PPO"
    raise PolicyError(f"{path}: the policy class comes from {module!r}, not from stable_baselines3 or sb3_contrib, "
                      f"and nothing says which algorithm saved it (neither rl-zoo3's {ENV_ID}/{ZOO_ARGS} naming it "
                      "nor PPO's clip range in the model)")


def _load_zip(path: str):
    """An SB3 (or sb3-contrib) model .zip of any algorithm, with a VecNormalize .pkl next to it if there is one."""
    package, algo = sb3_algorithm(path)
    try:  # heavy (about 2 s) and only needed for a user's .zip: imported on first use
        lib = importlib.import_module(package)
    except ImportError:
        raise PolicyError(f"{path} is a {package}.{algo} model; install {package.replace('_', '-')} to load it") \
            from None
    cls = getattr(lib, algo, None)
    if cls is None:
        raise PolicyError(f"{path}: {package} has no algorithm {algo!r} (saved with another version?)")
    try:
        model = cls.load(path, device="cpu")
    except Exception as exc:  # a damaged or incompatible file: reported with its cause
        raise PolicyError(f"{path} is not a loadable stable-baselines3 model ({algo}: {type(exc).__name__}: "
                          f"{str(exc)[:200]})") from None
    vn = _load_vecnormalize(path)
    if vn is not None and getattr(vn, "norm_obs", False):
        return _Normalized(model, vn.obs_rms.mean, vn.obs_rms.var, vn.epsilon, vn.clip_obs)
    return model


def load_run(run, task: str, env_kwargs: dict):
    """The object with ``predict`` for one run of a spec.

    Args:
        run: a scripted-law description (dict), a model path (str) or an object with ``predict``.
        task: the task it acts on (scripted laws are built for it).
        env_kwargs: the env settings it acts in (scripted laws take their controller settings from them).
    """
    if isinstance(run, dict):
        cfg = EnvConfig.from_kwargs({**env_kwargs, "task": task})
        if run["kind"] == "clf":
            return CLFPolicy(cfg)
        return PIDPolicy(cfg, gains=(run.get("gains") or {}).get(task))
    if isinstance(run, str):
        return _load_zip(run) if run.endswith(".zip") else load_safe(run)
    return run


def portable(run, policy) -> tuple:
    """What a worker process needs to rebuild ``policy`` (the loaded form of ``run``) without loading it again.

    Args:
        run: the spec's run (scripted-law description, model path or object).
        policy: what :func:`load_run` made of it in this process.

    Returns:
        ("build", run) for a scripted law (rebuilt in the worker: no file, no tuning), ("safe", files) for a
        safe-weights model (the bytes of its two files: no pickle, and a worker on another machine needs no copy
        of them), ("bytes", pickle) for another loaded model or object that pickles, or ("load", run) for a model
        that does not pickle (the worker loads it from its file).

    Raises:
        pickle.PicklingError, TypeError, AttributeError: a Python object given as a policy does not pickle.
    """
    if isinstance(run, dict):
        return ("build", run)
    if isinstance(run, str) and not run.endswith(".zip"):
        st_path, js_path = model_paths(run)
        with open(st_path, "rb") as f, open(js_path, encoding="utf-8") as g:
            return ("safe", {"name": os.path.basename(js_path)[:-len(".json")], "safetensors": f.read(),
                             "json": g.read()})
    try:
        return ("bytes", pickle.dumps(policy, protocol=pickle.HIGHEST_PROTOCOL))
    except Exception:  # e.g. a model with a lambda inside; a plain object has no file to fall back on
        if isinstance(run, str):
            return ("load", run)
        raise


def restore(item: tuple, task: str, env_kwargs: dict):
    """The policy object of a :func:`portable` item (in the process that runs its episodes).

    Args:
        item: what :func:`portable` returned, or ("object", policy) for an object already at hand.
        task: the task it acts on.
        env_kwargs: the env settings it acts in.
    """
    how, what = item
    if how == "safe":  # through the safe-weights loader (hashes and shapes checked), from a private folder
        with tempfile.TemporaryDirectory(prefix="ehss-policy-") as tmp:
            stem = os.path.join(tmp, what["name"])
            with open(stem + ".safetensors", "wb") as f, open(stem + ".json", "w", encoding="utf-8") as g:
                f.write(what["safetensors"])
                g.write(what["json"])
            return load_policy(stem)
    if how == "bytes":
        return pickle.loads(what)
    if how == "object":  # in the process that loaded it
        return what
    return load_run(what, task, env_kwargs)


def make_env(env_kwargs: dict) -> EHSSTrackingEnv:
    """The env a policy acts in (the class behind ``gym.make("EHSSTracking-v0")``, without wrappers)."""
    return EHSSTrackingEnv(**env_kwargs)


__all__ = ["PolicyError", "ZOO_ARGS", "ZOO_CONFIG", "ZOO_ALGOS", "ZooLoader", "zoo_params_dir", "read_zoo_record",
           "sb3_algorithm", "load_safe", "load_run", "portable", "restore", "make_env"]
