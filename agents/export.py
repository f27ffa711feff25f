"""Export a trained SB3 policy as safe weights (``PATH.safetensors`` + ``PATH.json``; format in
:mod:`ehss_gym.agents.safeweights`, which loads them without torch).

Exporting reads the torch model, so this module imports torch; training imports it, the evaluation does not.
"""

from __future__ import annotations

import json
import os
import pickle
import zipfile

import numpy as np
import torch
import torch.nn as nn
from gymnasium import spaces
from safetensors.torch import save
from stable_baselines3 import PPO, SAC
from stable_baselines3.common.distributions import (
    DiagGaussianDistribution,
    SquashedDiagGaussianDistribution,
    StateDependentNoiseDistribution,
)
from stable_baselines3.common.torch_layers import FlattenExtractor
from stable_baselines3.sac.policies import Actor as SACActor

from ehss_gym.infra.util import atomic_write, atomic_write_text

from .safeweights import ACTIVATIONS, FORMAT, SafeWeightsError, model_paths, sha256

# torch activation modules by safe-weights name; only the default arguments are supported
TORCH_ACTIVATIONS = {nn.Tanh: "tanh", nn.ReLU: "relu", nn.ELU: "elu", nn.LeakyReLU: "leaky_relu", nn.SiLU: "silu",
                     nn.GELU: "gelu", nn.Identity: "identity"}


def _activation_name(module: nn.Module) -> str:
    name = TORCH_ACTIVATIONS.get(type(module))
    non_default = {"leaky_relu": lambda m: m.negative_slope != 0.01, "gelu": lambda m: m.approximate != "none",
                   "elu": lambda m: m.alpha != 1.0}
    if name is None or non_default.get(name, lambda m: False)(module):
        raise SafeWeightsError(f"activation {module!r} is not supported; supported (with default arguments): "
                               f"{list(ACTIVATIONS)}")
    return name


def _box_to_json(space) -> dict:
    if not isinstance(space, spaces.Box):
        raise SafeWeightsError(f"only Box spaces are supported, got {space!r}")
    return {"type": "Box", "low": np.asarray(space.low, dtype=np.float64).reshape(-1).tolist(),
            "high": np.asarray(space.high, dtype=np.float64).reshape(-1).tolist(), "shape": list(space.shape),
            "dtype": np.dtype(space.dtype).name}


def _jsonable(obj):
    """Plain JSON values (tuples -> lists, numpy scalars -> Python); raises for anything else."""
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, (np.floating, np.integer, np.bool_)):
        return obj.item()
    if obj is None or isinstance(obj, (bool, int, float, str)):
        return obj
    raise SafeWeightsError(f"value {obj!r} of type {type(obj).__name__} cannot be stored in the JSON config")


def _check_spaces(policy) -> None:
    if not isinstance(policy.observation_space, spaces.Box) or len(policy.observation_space.shape) != 1:
        raise SafeWeightsError(f"observation space must be a 1-D Box, got {policy.observation_space!r}")
    if not isinstance(policy.action_space, spaces.Box) or len(policy.action_space.shape) != 1:
        raise SafeWeightsError(f"action space must be a 1-D Box, got {policy.action_space!r}")


def _check_flatten(extractor, what: str) -> None:
    if not isinstance(extractor, FlattenExtractor):
        raise SafeWeightsError(f"only the flatten features extractor is supported, got {type(extractor).__name__} "
                               f"({what})")


def _check_exportable(policy) -> None:
    _check_spaces(policy)
    dist = getattr(policy, "action_dist", None)
    sde = isinstance(dist, StateDependentNoiseDistribution)
    if not isinstance(dist, DiagGaussianDistribution) and not sde:
        raise SafeWeightsError("only a diagonal-Gaussian or a gSDE action distribution, or SAC's squashed Gaussian "
                               f"actor, is supported; got {type(policy).__name__}")
    if sde and (dist.use_expln or not dist.full_std or dist.bijector is not None):
        raise SafeWeightsError("a gSDE policy is supported with SB3's defaults only (use_expln=False, full_std=True, "
                               "squash_output=False)")
    if getattr(policy, "squash_output", False):
        raise SafeWeightsError("squash_output=True policies are not supported")
    _check_flatten(policy.pi_features_extractor, "the policy's")


def _check_sac(actor: SACActor) -> None:
    """Refuse a SAC actor the squashed head cannot reproduce. A shared features extractor is accepted: the flatten
    extractor has no parameters, so sharing it with the critics changes nothing the actor computes."""
    _check_spaces(actor)
    if actor.use_sde:
        raise SafeWeightsError("a gSDE SAC actor (use_sde=True) is not supported: its mean is clipped (clip_mean) and "
                               "its noise is a state-dependent matrix under the tanh; train SAC without gSDE")
    if not isinstance(actor.action_dist, SquashedDiagGaussianDistribution) or not isinstance(actor.mu, nn.Linear) \
            or not isinstance(actor.log_std, nn.Linear):
        raise SafeWeightsError("only SB3's SAC actor (a squashed diagonal Gaussian with Linear mu and log_std layers) "
                               "is supported")
    _check_flatten(actor.features_extractor, "the SAC actor's")


def _f32(t: torch.Tensor) -> torch.Tensor:
    return t.detach().cpu().to(torch.float32).contiguous().clone()


def _linear(tensors: dict, name: str, layer: nn.Linear) -> None:
    tensors[f"{name}.weight"] = _f32(layer.weight)
    tensors[f"{name}.bias"] = _f32(layer.bias)


def _hidden_tensors(net: nn.Sequential, tensors: dict, what: str) -> tuple[list[int], str]:
    """Store the [Linear -> activation] x L layers of ``net`` as ``pi.<i>.*``; (hidden sizes, activation name)."""
    hidden: list[int] = []
    act_names: list[str] = []
    for mod in net:
        if isinstance(mod, nn.Linear):
            _linear(tensors, f"pi.{len(hidden)}", mod)
            hidden.append(int(mod.out_features))
        else:
            act_names.append(_activation_name(mod))
    if len(act_names) != len(hidden) or len(set(act_names)) > 1:
        raise SafeWeightsError(f"{what} must alternate Linear and one kind of activation, got {act_names}")
    return hidden, act_names[0] if act_names else "identity"


def _arch(policy, hidden: list[int], activation: str) -> dict:
    return {"obs_dim": int(policy.observation_space.shape[0]), "hidden": hidden, "activation": activation,
            "act_dim": int(policy.action_space.shape[0])}


def _actor_critic_tensors(policy) -> tuple[dict, dict]:
    _check_exportable(policy)
    tensors: dict[str, torch.Tensor] = {}
    hidden, activation = _hidden_tensors(policy.mlp_extractor.policy_net, tensors, "policy_net")
    _linear(tensors, "action", policy.action_net)
    tensors["log_std"] = _f32(policy.log_std)
    arch = _arch(policy, hidden, activation)
    if isinstance(policy.action_dist, StateDependentNoiseDistribution):  # log_std: the (features, actions) matrix
        arch["exploration"] = "gsde"
    return tensors, arch


def _sac_tensors(actor: SACActor) -> tuple[dict, dict]:
    """SAC's actor: ``latent_pi`` as the hidden layers, ``mu`` as the action layer, its state-dependent ``log_std``
    layer as ``log_std.weight``/``.bias``, and ``"head": "squashed"`` (tanh, then the rescale to the action Box)."""
    _check_sac(actor)
    tensors: dict[str, torch.Tensor] = {}
    hidden, activation = _hidden_tensors(actor.latent_pi, tensors, "the SAC actor's latent_pi")
    _linear(tensors, "action", actor.mu)
    _linear(tensors, "log_std", actor.log_std)
    return tensors, {**_arch(actor, hidden, activation), "head": "squashed"}


def policy_tensors(model, vecnormalize=None) -> tuple[dict, dict, dict | None]:
    """The tensors, architecture and normalisation config of an SB3 actor-critic policy or SAC actor.

    Args:
        model: a stable-baselines3 PPO/A2C model (or its ``.policy``) with an MLP policy, a flatten features
            extractor and a Gaussian (or gSDE with SB3's defaults) Box action; or a SAC model (or its ``.policy``)
            with an MLP actor, a flatten features extractor and no gSDE (exported with the squashed head).
        vecnormalize: the ``VecNormalize`` wrapper the model was trained with, or None.

    Returns:
        (tensors name -> torch tensor, architecture dict, obs-normalisation dict or None).

    Raises:
        SafeWeightsError: a policy the format cannot reproduce; the message names why.
    """
    policy = getattr(model, "policy", model)
    actor = policy if isinstance(policy, SACActor) else getattr(policy, "actor", None)
    if isinstance(actor, SACActor):
        tensors, arch = _sac_tensors(actor)
    else:
        tensors, arch = _actor_critic_tensors(policy)
    norm = None
    if vecnormalize is not None and vecnormalize.norm_obs:
        rms = vecnormalize.obs_rms
        if isinstance(rms, dict):
            raise SafeWeightsError("dict observations are not supported")
        tensors["obs_mean"] = torch.from_numpy(np.asarray(rms.mean, dtype=np.float64).copy())
        tensors["obs_var"] = torch.from_numpy(np.asarray(rms.var, dtype=np.float64).copy())
        norm = {"epsilon": float(vecnormalize.epsilon), "clip_obs": float(vecnormalize.clip_obs)}
    return tensors, arch, norm


def export_policy(model, path, *, vecnormalize=None, name: str | None = None, env_id: str = "EHSSTracking-v0",
                  env_kwargs: dict | None = None, metadata: dict | None = None) -> tuple[str, str]:
    """Write ``path.safetensors`` and ``path.json`` for an SB3 policy (format: :mod:`ehss_gym.agents.safeweights`).

    Both files are written atomically, the tensors first, so a crash leaves no JSON pointing to a
    half-written tensor file.

    Args:
        model: the SB3 model (PPO/A2C with an MLP policy, or SAC with an MLP actor) or its policy.
        path: output stem (``.json`` / ``.safetensors`` suffixes are stripped); folders are created.
        vecnormalize: the VecNormalize wrapper whose observation statistics the policy expects, or None.
        name: model name (default: the stem's file name).
        env_id: the Gymnasium id of the env the policy acts in.
        env_kwargs: keyword arguments of ``gym.make(env_id, ...)`` the policy was trained with (JSON values).
        metadata: free-form JSON-able extras (training config, scores, ...).

    Returns:
        (safetensors path, json path).
    """
    st_path, js_path = model_paths(path)
    tensors, arch, norm = policy_tensors(model, vecnormalize)
    policy = getattr(model, "policy", model)
    blob = save(tensors)
    config = {
        "format": FORMAT,
        "name": name or os.path.basename(st_path[: -len(".safetensors")]),
        "sha256": sha256(blob),
        "architecture": arch,
        "observation_space": _box_to_json(policy.observation_space),
        "action_space": _box_to_json(policy.action_space),
        "obs_normalization": norm,
        "env_id": env_id,
        "env_kwargs": _jsonable(env_kwargs or {}),
        "metadata": _jsonable(metadata or {}),
    }
    atomic_write(st_path, lambda f: f.write(blob))
    atomic_write_text(js_path, json.dumps(config, indent=1, sort_keys=True, allow_nan=False) + "\n")
    return st_path, js_path


def export_saved_model(folder, *, algo: str, name: str, metadata: dict | None = None) -> str:
    """Export the SB3 files a training run saved in ``folder`` (``model.zip``, ``vecnormalize.pkl`` and
    ``model.json``, as ``ehss train`` writes ``best/`` and ``final/``) as safe weights ``folder/policy``: for runs
    trained before their algorithm's policies were exported at the end of training (SAC).

    ``model.zip`` and ``vecnormalize.pkl`` are unpickled: call this on run folders you trust (your own runs).

    Args:
        folder: the run's ``best/`` (or ``final/``) folder.
        algo: the SB3 algorithm that saved ``model.zip``, "ppo" or "sac".
        name: the model name recorded in ``policy.json``.
        metadata: free-form JSON-able extras (the run's config, step and validation scores).

    Returns:
        The stem written, ``folder/policy``.

    Raises:
        SafeWeightsError: a missing or unreadable file, or a policy the format cannot reproduce (the reason named).
    """
    classes = {"ppo": PPO, "sac": SAC}
    if algo not in classes:
        raise SafeWeightsError(f"algo must be one of {sorted(classes)}, got {algo!r}")
    paths = [os.path.join(folder, f) for f in ("model.zip", "vecnormalize.pkl", "model.json")]
    try:
        model = classes[algo].load(paths[0], device="cpu")
        with open(paths[1], "rb") as f:
            vecnormalize = pickle.load(f)  # VecNormalize without its env: the statistics are all the export reads
        with open(paths[2], encoding="utf-8") as f:
            env_kwargs = json.load(f)["env_kwargs"]
    except (OSError, EOFError, ValueError, KeyError, pickle.UnpicklingError, zipfile.BadZipFile) as exc:
        raise SafeWeightsError(f"{folder}: the saved {algo.upper()} model cannot be read ({type(exc).__name__}: "
                               f"{exc})") from None
    stem = os.path.join(folder, "policy")
    export_policy(model, stem, vecnormalize=vecnormalize, name=name, env_kwargs=env_kwargs, metadata=metadata)
    return stem


__all__ = ["export_policy", "export_saved_model", "policy_tensors", "TORCH_ACTIVATIONS"]
