"""Safe weights: a trained SB3 policy as plain tensors plus a JSON config, loaded without unpickling.

An SB3 ``.zip`` (and a ``VecNormalize`` ``.pkl``) is deserialised with pickle, so opening a downloaded
file can run code. This module writes the parts of a policy that its *deterministic* action needs, as
a safetensors file (raw little-endian arrays behind a JSON header; reading it cannot run code) and a
JSON config (:func:`ehss_gym.agents.export.export_policy`, from the torch model), and reads them back
(:func:`load_policy`, here) into a small MLP that reproduces SB3's ``predict`` exactly:

    obs (float32) --VecNormalize--> clip((obs - mean) / sqrt(var + eps), -clip_obs, clip_obs) as float32
        --> [Linear -> activation] x L (SB3's ``mlp_extractor.policy_net``) --> Linear (``action_net``)
        --> clip to the action space bounds   (SB3 ``predict`` for a Box action, no squashing)

or, for a SAC actor (architecture ``head`` = "squashed": ``latent_pi`` as the hidden layers, ``mu`` as the action
layer), the squashed mean rescaled to the action Box as SB3's ``unscale_action`` does, in float32:

        ... --> Linear (``mu``) --> a = tanh(.) --> low + 0.5 (a + 1) (high - low) --> clip to the bounds (a no-op
        but for a rounding overshoot of the rescale, which SB3 leaves unclipped)

Files of a model with stem ``PATH`` (``PATH`` may end in ``.json`` or ``.safetensors``; either is
stripped):

- ``PATH.safetensors``: tensors ``pi.{i}.weight`` / ``pi.{i}.bias`` (hidden layers, float32),
  ``action.weight`` / ``action.bias`` (float32), ``log_std`` (float32, the Gaussian exploration
  scale, used only by ``predict(..., deterministic=False)``; a squashed head has instead SAC's state-dependent
  log-std layer, ``log_std.weight`` (act_dim, last hidden size) and ``log_std.bias`` (act_dim), float32), and, with
  observation normalisation, ``obs_mean`` / ``obs_var`` (float64, VecNormalize's running statistics).
- ``PATH.json``: ``format`` (= :data:`FORMAT`), ``name``, ``sha256`` of the safetensors file,
  ``architecture`` (``obs_dim``, ``hidden`` sizes, ``activation``, ``act_dim``, and ``exploration`` = "gsde" for a
  policy trained with gSDE, whose ``log_std`` is then the (last hidden size, act_dim) matrix of its noise's scales
  and whose stochastic action adds the last hidden features times a Gaussian matrix of those scales, drawn per call;
  ``head`` = "squashed" for a SAC actor, whose stochastic action is tanh(mean + exp(log_std) N(0, 1)) with log_std
  = the log-std layer of the last hidden features clamped to [-20, 2] as SB3 does, rescaled to the bounds; an absent
  ``head`` is the Gaussian head of PPO/A2C),
  ``observation_space``
  and ``action_space`` (Box low/high/shape/dtype), ``obs_normalization`` (null or ``epsilon`` and
  ``clip_obs``), ``env_id`` and ``env_kwargs`` (what ``gym.make`` needs to rebuild the training env),
  and ``metadata`` (free-form JSON: training config, scores, ...).

:func:`load_policy` refuses, with a :class:`SafeWeightsError` (a ValueError) naming the problem, a
file whose SHA-256 differs from the one recorded in the JSON, a missing or extra tensor, a tensor of
the wrong shape or dtype, a non-finite value, or a JSON config with unknown or missing fields. The
hash guards integrity (a corrupted or edited file), not authenticity: anyone who edits both files can
change the weights, but never make the loader run code.

Loading needs no torch: the file is parsed with safetensors' numpy API and checked with numpy. The forward
pass imports torch on its first call, because torch's float32 kernels are what SB3's ``predict`` runs: numpy
gives the same actions only up to the last bit (numpy's ``tanh`` rounds differently, and its BLAS sums a
single observation's dot products in another order; measured on the shipped policies, 80 % of the actions
of a trained policy differed in the last bit), and the evaluation's results would then change.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import sys
from dataclasses import dataclass, field

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from safetensors import SafetensorError
from safetensors.numpy import load

from ehss_gym.core.jit import jit_noalloc
from ehss_gym.envs import ENV_ID
from ehss_gym.envs.config import in_legacy_loop

FORMAT = "ehss-gym-safeweights/1"
ACTIVATIONS = ("tanh", "relu", "elu", "leaky_relu", "silu", "gelu", "identity")
JSON_KEYS = ("format", "name", "sha256", "architecture", "observation_space", "action_space", "obs_normalization",
             "env_id", "env_kwargs", "metadata")
ARCH_KEYS = ("obs_dim", "hidden", "activation", "act_dim")
EXPLORATIONS = ("gsde",)  # the optional architecture key "exploration" (absent: the diagonal Gaussian)
HEADS = ("squashed",)  # the optional architecture key "head" (absent: the Gaussian head of PPO/A2C; squashed: SAC's)
ARCH_OPTIONAL = {"exploration": EXPLORATIONS, "head": HEADS}
LOG_STD_RANGE = (-20.0, 2.0)  # SB3 SAC's clamp of its state-dependent log std (LOG_STD_MIN, LOG_STD_MAX)
SPACE_KEYS = ("type", "low", "high", "shape", "dtype")


# the shipped policies: ehss_gym/models (package data of the top package; this module is ehss_gym.agents)
MODELS_DIR = os.path.join(os.path.dirname(os.path.abspath(sys.modules["ehss_gym"].__file__)), "models")


class SafeWeightsError(ValueError):
    """A safe-weights file is missing, malformed or does not match its recorded hash."""


def model_paths(path) -> tuple[str, str]:
    """(``stem.safetensors``, ``stem.json``) of a model path given as the stem or either file."""
    stem = os.fspath(path)
    for ext in (".safetensors", ".json"):
        if stem.endswith(ext):
            stem = stem[: -len(ext)]
    return stem + ".safetensors", stem + ".json"


def sha256(data: bytes) -> str:
    """SHA-256 of ``data`` as 64 lowercase hex digits (what the JSON config records of the tensor file)."""
    return hashlib.sha256(data).hexdigest()


def _box_from_json(d, what: str) -> spaces.Box:
    if not isinstance(d, dict) or sorted(d) != sorted(SPACE_KEYS) or d["type"] != "Box":
        raise SafeWeightsError(f"{what} must be a dict with keys {list(SPACE_KEYS)} and type 'Box', got {d!r}")
    shape = d["shape"]
    if not isinstance(shape, list) or not all(isinstance(s, int) and not isinstance(s, bool) and s >= 1
                                              for s in shape):
        raise SafeWeightsError(f"{what}.shape must be a list of positive integers, got {shape!r}")
    if d["dtype"] not in ("float32", "float64"):
        raise SafeWeightsError(f"{what}.dtype must be 'float32' or 'float64', got {d['dtype']!r}")
    size = int(np.prod(shape))
    try:
        low = np.asarray(d["low"], dtype=np.float64)
        high = np.asarray(d["high"], dtype=np.float64)
    except (TypeError, ValueError):
        raise SafeWeightsError(f"{what}.low/high must be lists of numbers") from None
    if low.shape != (size,) or high.shape != (size,) or np.isnan(low).any() or np.isnan(high).any() \
            or (low > high).any():
        raise SafeWeightsError(f"{what}.low/high must be {size} numbers each with low <= high")
    dtype = np.dtype(d["dtype"])
    return spaces.Box(low.reshape(shape).astype(dtype), high.reshape(shape).astype(dtype), shape=tuple(shape),
                      dtype=dtype)


# ---------------------------------------------------------------------------------------------------
# Load


def _check_config(cfg, js_path: str) -> None:
    if not isinstance(cfg, dict):
        raise SafeWeightsError(f"{js_path}: the JSON config must be an object")
    missing = [k for k in JSON_KEYS if k not in cfg]
    extra = sorted(set(cfg) - set(JSON_KEYS))
    if missing or extra:
        raise SafeWeightsError(f"{js_path}: JSON config keys must be exactly {list(JSON_KEYS)}; missing {missing}, "
                               f"unexpected {extra}")
    if cfg["format"] != FORMAT:
        raise SafeWeightsError(f"{js_path}: format must be {FORMAT!r}, got {cfg['format']!r}")
    if not isinstance(cfg["name"], str) or not cfg["name"]:
        raise SafeWeightsError(f"{js_path}: name must be a non-empty string")
    h = cfg["sha256"]
    if not isinstance(h, str) or len(h) != 64 or any(c not in "0123456789abcdef" for c in h):
        raise SafeWeightsError(f"{js_path}: sha256 must be 64 lowercase hex digits, got {h!r}")
    arch = cfg["architecture"]
    if not isinstance(arch, dict) or sorted(set(arch) - set(ARCH_OPTIONAL)) != sorted(ARCH_KEYS):
        raise SafeWeightsError(f"{js_path}: architecture must have exactly the keys {list(ARCH_KEYS)} (and optionally "
                               f"{list(ARCH_OPTIONAL)}), got {arch!r}")
    for key, allowed in ARCH_OPTIONAL.items():
        if key in arch and arch[key] not in allowed:
            raise SafeWeightsError(f"{js_path}: architecture {key} must be one of {list(allowed)}, got {arch[key]!r}")
    if "exploration" in arch and "head" in arch:
        raise SafeWeightsError(f"{js_path}: architecture exploration {arch['exploration']!r} has no squashed form "
                               "(gSDE is stored for the Gaussian head only)")

    def pos_int(v):
        return isinstance(v, int) and not isinstance(v, bool) and v >= 1

    if not pos_int(arch["obs_dim"]) or not pos_int(arch["act_dim"]) or not isinstance(arch["hidden"], list) \
            or not all(pos_int(v) for v in arch["hidden"]):
        raise SafeWeightsError(f"{js_path}: architecture obs_dim, act_dim and hidden sizes must be positive "
                               f"integers, got {arch!r}")
    if arch["activation"] not in ACTIVATIONS:
        raise SafeWeightsError(f"{js_path}: activation must be one of {list(ACTIVATIONS)}, got "
                               f"{arch['activation']!r}")
    norm = cfg["obs_normalization"]
    if norm is not None:
        if not isinstance(norm, dict) or sorted(norm) != ["clip_obs", "epsilon"] or not all(
                isinstance(norm[k], (int, float)) and not isinstance(norm[k], bool) and math.isfinite(norm[k])
                and norm[k] > 0 for k in norm):
            raise SafeWeightsError(f"{js_path}: obs_normalization must be null or {{'epsilon': >0, 'clip_obs': >0}}, "
                                   f"got {norm!r}")
    if not isinstance(cfg["env_id"], str) or not isinstance(cfg["env_kwargs"], dict) \
            or not isinstance(cfg["metadata"], dict):
        raise SafeWeightsError(f"{js_path}: env_id must be a string, env_kwargs and metadata objects")


def expected_tensors(cfg: dict) -> dict[str, tuple[tuple[int, ...], str]]:
    """Name -> (shape, dtype) of every tensor a config implies; nothing else may be in the file."""
    arch = cfg["architecture"]
    out = {}
    last = arch["obs_dim"]
    for i, hdim in enumerate(arch["hidden"]):
        out[f"pi.{i}.weight"] = ((hdim, last), "float32")
        out[f"pi.{i}.bias"] = ((hdim,), "float32")
        last = hdim
    out["action.weight"] = ((arch["act_dim"], last), "float32")
    out["action.bias"] = ((arch["act_dim"],), "float32")
    last_hidden = (arch["hidden"] or [arch["obs_dim"]])[-1]
    if arch.get("head") == "squashed":  # SAC's state-dependent log-std layer over the last hidden features
        out["log_std.weight"] = ((arch["act_dim"], last_hidden), "float32")
        out["log_std.bias"] = ((arch["act_dim"],), "float32")
    elif arch.get("exploration") == "gsde":  # the noise matrix's log scales over the last hidden features
        out["log_std"] = ((last_hidden, arch["act_dim"]), "float32")
    else:
        out["log_std"] = ((arch["act_dim"],), "float32")
    if cfg["obs_normalization"] is not None:
        out["obs_mean"] = ((arch["obs_dim"],), "float64")
        out["obs_var"] = ((arch["obs_dim"],), "float64")
    return out


@jit_noalloc
def normalize_into(obs, mean, std, clip, out):
    """VecNormalize's normalisation of a batch obs (B, obs_dim) into ``out`` (B, obs_dim) float32: each entry's
    ``(obs - mean) / std`` in float64, clipped to +-clip as ``np.maximum`` then ``np.minimum`` do (a NaN stays NaN),
    then rounded to float32 as ``astype`` rounds. The same arithmetic as those ufuncs, entry by entry, in one call:
    the ufuncs and their temporaries cost more than the arithmetic on the few observations of an agent step."""
    lo = -clip
    for i in range(obs.shape[0]):
        for j in range(obs.shape[1]):
            z = (obs[i, j] - mean[j]) / std[j]
            z = z if (z >= lo or z != z) else lo
            z = z if (z <= clip or z != z) else clip
            out[i, j] = z


def _torch():
    """The torch module, imported at the first forward pass."""
    import torch  # the forward pass only (see the module docstring): loading a policy stays torch-free

    return torch


def _activation(name: str):
    """torch's function of an activation name (one of :data:`ACTIVATIONS`)."""
    torch = _torch()
    F = torch.nn.functional
    return {"tanh": torch.tanh, "relu": torch.relu, "elu": F.elu, "leaky_relu": F.leaky_relu, "silu": F.silu,
            "gelu": F.gelu, "identity": lambda v: v}[name]


def _torch_forward(layers, act_name: str, head):
    """The forward pass [Linear -> activation] x L -> Linear in torch's float32 kernels, SB3's arithmetic bit for bit:
    a function of a batch x (B, obs_dim) (with ``features``: also the last hidden features), made once per policy with
    the weights as torch tensors sharing the arrays' memory."""
    torch = _torch()

    F = torch.nn.functional
    act = _activation(act_name)
    tl = [(torch.from_numpy(w), torch.from_numpy(b)) for w, b in layers]
    th = tuple(map(torch.from_numpy, head))

    # No torch.no_grad(): none of these tensors requires a gradient (from_numpy and as_tensor make none that does), so
    # autograd records nothing anyway, and entering and leaving that context took a tenth of a small policy's call.
    def forward(x: np.ndarray, features: bool = False):
        h = torch.as_tensor(x).float()
        for w, b in tl:
            h = act(F.linear(h, w, b))
        out = F.linear(h, *th).numpy()
        return (out, h.numpy()) if features else out

    return forward


@dataclass
class SafePolicy:
    """A loaded safe-weights policy with SB3's ``predict`` (see the module docstring).

    Attributes:
        name: model name.
        observation_space, action_space: gymnasium Box spaces.
        env_id, env_kwargs: how to rebuild the env (``gym.make(env_id, **env_kwargs)``).
        metadata: training config and scores stored with the model.
        obs_normalization: None or {"epsilon", "clip_obs"} of the VecNormalize statistics.
        path: the JSON file it was loaded from.
        tensors: name -> numpy array (float32 weights, float64 normalisation statistics).
        activation: hidden activation name (one of :data:`ACTIVATIONS`).
        head: None (the Gaussian head, clipped to the bounds) or "squashed" (SAC's: tanh, then the rescale to the
            bounds).
        seed: seed of the Gaussian samples of ``predict(..., deterministic=False)``.
    """

    name: str
    observation_space: object
    action_space: object
    env_id: str
    env_kwargs: dict
    metadata: dict
    obs_normalization: dict | None
    path: str
    tensors: dict = field(repr=False)
    activation: str = "tanh"
    head: str | None = None
    seed: int | None = None

    def __post_init__(self):
        n_hidden = sum(1 for k in self.tensors if k.startswith("pi.") and k.endswith(".weight"))
        self._layers = [(self.tensors[f"pi.{i}.weight"], self.tensors[f"pi.{i}.bias"]) for i in range(n_hidden)]
        self._head = (self.tensors["action.weight"], self.tensors["action.bias"])
        self._torch_fn = None  # the forward pass in torch, made at the first call (loading stays torch-free)
        self._rng = np.random.default_rng(self.seed)
        if self.obs_normalization is not None:
            self._mean = self.tensors["obs_mean"]
            self._std = np.sqrt(self.tensors["obs_var"] + self.obs_normalization["epsilon"])
            self._clip = float(self.obs_normalization["clip_obs"])
        self._low = np.asarray(self.action_space.low)
        self._high = np.asarray(self.action_space.high)
        if self.head == "squashed":
            self._log_std_layer = (self.tensors["log_std.weight"], self.tensors["log_std.bias"])

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_torch_fn": None}  # the forward pass is made again where the policy is unpickled

    def _forward(self, obs_norm: np.ndarray, features: bool = False):
        """:func:`_torch_forward` of this policy's weights (made at the first call)."""
        if self._torch_fn is None:
            self._torch_fn = _torch_forward(self._layers, self.activation, self._head)
        return self._torch_fn(obs_norm, features)

    def normalize_obs(self, obs: np.ndarray) -> np.ndarray:
        """VecNormalize's observation normalisation (float64 arithmetic, float32 result), or the identity."""
        if self.obs_normalization is None:
            return obs
        obs = np.asarray(obs)
        D = self._mean.shape[0]
        if obs.ndim == 0 or obs.shape[-1] != D:
            raise ValueError(f"observation must have shape ({D},) or (..., {D}) for model {self.name!r}, got "
                             f"{obs.shape}")
        rows = obs.reshape(-1, D)
        if rows.dtype not in (np.float32, np.float64):  # exact in float64, as the ufuncs' own cast
            rows = rows.astype(np.float64)
        out = np.empty(rows.shape, dtype=np.float32)
        normalize_into(rows, self._mean, self._std, self._clip, out)
        return out.reshape(obs.shape)

    def mean_action(self, obs_norm: np.ndarray) -> np.ndarray:
        """The Gaussian mean for a batch of normalised observations (B, obs_dim): in action units before clipping, or
        (squashed head) before the tanh and the rescale."""
        return self._forward(obs_norm)

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        """SB3-style prediction: (action, state). Accepts one observation or a batch (B, obs_dim).

        Args:
            observation: raw env observation(s) (normalisation is applied here).
            state, episode_start: ignored (no recurrent state); ``state`` is returned unchanged.
            deterministic: the mean action (True, default; squashed head: tanh of the mean, rescaled) or a Gaussian
                sample with the stored log_std (gSDE: the features times a Gaussian matrix drawn for this call;
                squashed head: tanh of a sample with the state-dependent log std, rescaled).
        """
        obs = np.array(observation)
        shape = self.observation_space.shape
        if obs.shape == shape:
            batched = False
        elif obs.shape[1:] == shape:
            batched = True
        else:
            raise ValueError(f"observation must have shape {shape} or (batch, {', '.join(map(str, shape))}) for "
                             f"model {self.name!r}, got {obs.shape}")
        obs = obs.reshape((-1, *shape))
        if deterministic:
            act = self._deterministic(self.normalize_obs(obs))
        else:
            if self.head == "squashed":
                act = self._squashed_action(self.normalize_obs(obs), False)
            elif self.tensors["log_std"].ndim == 2:  # gSDE: the features times a Gaussian matrix of the stored scales
                act, phi = self._forward(self.normalize_obs(obs), True)
                eps = np.exp(self.tensors["log_std"]) * self._rng.standard_normal(self.tensors["log_std"].shape)
                act = (act + phi @ eps).astype(np.float32)
            else:
                act = self.mean_action(self.normalize_obs(obs))
                std = np.exp(self.tensors["log_std"])
                act = (act + std * self._rng.standard_normal(act.shape)).astype(np.float32)
            act = self._clip_action(act)
        if not batched:
            act = act.squeeze(axis=0)
        return act, state

    @staticmethod
    def side_by_side(policies: list, n: int) -> StackedPolicies | None:
        """``policies`` acting on ``n`` rows each in one forward pass, where that gives their actions bit for bit
        (:meth:`StackedPolicies.fit`); None otherwise."""
        return StackedPolicies.fit(policies, n)

    def _clip_action(self, act: np.ndarray) -> np.ndarray:
        """Actions (B, *action shape) clipped to the bounds (as ``np.clip``: a NaN stays NaN)."""
        return np.minimum(np.maximum(act.reshape((-1, *self.action_space.shape)), self._low), self._high)

    def _deterministic(self, obs_norm: np.ndarray) -> np.ndarray:
        """The deterministic actions (B, *action shape) of normalised observations (B, obs_dim): the mean clipped to
        the bounds, or (squashed head) tanh of the mean rescaled to them."""
        if self.head == "squashed":
            return self._clip_action(self._squashed_action(obs_norm, True))
        return self._clip_action(self.mean_action(obs_norm))

    def _squashed_action(self, obs_norm: np.ndarray, deterministic: bool) -> np.ndarray:
        """SAC's action: tanh of the mean (or of a sample with the clamped state-dependent log std), rescaled from
        [-1, 1] to the bounds as SB3's ``unscale_action`` (float32 arithmetic for a float32 Box)."""
        torch = _torch()  # torch's tanh is SB3's, bit for bit

        mean, phi = self._forward(obs_norm, True)
        if not deterministic:
            w, b = self._log_std_layer
            std = np.exp(np.clip(phi @ w.T + b, *LOG_STD_RANGE))
            mean = (mean + std * self._rng.standard_normal(mean.shape)).astype(np.float32)
        with torch.no_grad():
            a = torch.tanh(torch.from_numpy(mean)).numpy()
        return self._unscale(a)

    def _unscale(self, a: np.ndarray) -> np.ndarray:
        """Squashed actions a in [-1, 1] rescaled to the bounds as SB3's ``unscale_action`` (float32 arithmetic)."""
        return self._low + (0.5 * (a + 1.0) * (self._high - self._low))

    def make_env(self, **overrides) -> gym.Env:
        """``gym.make(env_id, **env_kwargs, **overrides)``: the env this policy was trained for."""
        return gym.make(self.env_id, **{**self.env_kwargs, **overrides})


class StackedPolicies:
    """Safe-weights policies of one architecture side by side, each acting on its own ``n`` rows of a batch (S * n,
    obs_dim) in policy order, with their deterministic actions from one forward pass: each hidden layer one batched
    matrix product over the policies (torch's ``baddbmm`` of the stacked weights) instead of one ``linear`` per
    policy. The action of every row is the one its policy's :meth:`SafePolicy.predict` gives for its own n rows.

    torch's call overhead, not its arithmetic, is most of a small policy's forward pass (64 x 64 layers, a few
    dozen rows or one), so S policies in one pass cost little more than one. A batched product is another kernel
    than the per-policy ``linear``, and the two agree bit for bit only in some orientations and shapes. Measured with
    torch 2.13 on MKL's AVX2 path (random inputs, 1 to 128 rows per policy, 6,000 to 96,000 outputs per case):

    - a 64-wide hidden layer as rows times weights (x W^T, ``linear``'s own orientation) agreed from 2 rows up, as
      weights times columns (W x^T) at every row count;
    - the 2-wide action layer as x W^T agreed from 4 rows up (a 1-wide one from 7), as W x^T from 4 up; below, no
      batched form agreed (one row: 68 % of the outputs differed).

    So from :attr:`MIN_ROWS` rows per policy up every layer is batched as x W^T; below, the hidden layers are batched
    as W x^T and the action layer stays one ``linear`` per policy. :meth:`fit` makes a stack only after it gave the
    per-policy actions bit for bit on :attr:`PROBE_BATCHES` probe batches of the shape in use (elsewhere the caller
    keeps the per-policy passes).

    Args:
        policies: the policies (S of them), in row order.
        n: rows per policy.
    """

    MIN_ROWS = 8  # rows per policy from which the action layer is batched too (twice the measured threshold)
    PROBE_BATCHES = 16  # random normal batches (seed 0) on which the stack must give the per-policy actions

    def __init__(self, policies: list, n: int):
        torch = _torch()

        p0 = policies[0]
        self.policies, self.n = list(policies), int(n)
        self.obs_dim = p0.observation_space.shape[0]
        self.act_shape = p0.action_space.shape
        self._act = _activation(p0.activation)
        self._squashed = p0.head == "squashed"
        self._rows = self.n >= self.MIN_ROWS  # x W^T for every layer (else W x^T, and the action layer per policy)

        # per layer (the action layer last): the policies' weights (S, out, in) and biases (S, out), as torch tensors
        layers = [tuple(torch.from_numpy(np.stack(arrays)) for arrays in zip(*per_policy))
                  for per_policy in zip(*([*p._layers, p._head] for p in policies))]
        if self._rows:  # the weights seen transposed (S, in, out), as linear sees its weight; biases (S, 1, out)
            self._hidden = [(w.transpose(1, 2), b[:, None, :]) for w, b in layers[:-1]]
            self._head = (layers[-1][0].transpose(1, 2), layers[-1][1][:, None, :])
        else:  # the weights (S, out, in) times the rows seen as columns; biases (S, out, 1)
            self._hidden = [(w, b[:, :, None]) for w, b in layers[:-1]]
            self._head = [tuple(map(torch.from_numpy, p._head)) for p in policies]
        self._norm = p0.obs_normalization is not None
        self._x = np.empty((len(policies) * self.n, self.obs_dim), dtype=np.float32)

    @classmethod
    def fit(cls, policies: list, n: int) -> StackedPolicies | None:
        """The stack of ``policies`` at ``n`` rows each, or None where it would not give their actions bit for bit:
        policies of other classes or architectures (hidden sizes, activation, head, normalisation or action bounds),
        fewer than two, or a probe batch (random normal inputs, seeded, of the shape in use) on which a batched
        product rounds differently from the per-policy one."""
        if len(policies) < 2 or n < 1 or any(type(p) is not SafePolicy for p in policies):
            return None
        p0 = policies[0]

        def shape(p):
            return ([w.shape for w, _ in p._layers], p._head[0].shape, p.activation, p.head,
                    p.obs_normalization is None)

        if any(shape(p) != shape(p0) or not (np.array_equal(p._low, p0._low) and np.array_equal(p._high, p0._high))
               for p in policies[1:]):
            return None
        stacked = cls(policies, n)
        rng = np.random.default_rng(0)
        for _ in range(cls.PROBE_BATCHES):
            probe = rng.standard_normal((len(policies) * n, stacked.obs_dim)).astype(np.float32)
            alone = np.concatenate([p._deterministic(probe[i * n:(i + 1) * n]) for i, p in enumerate(policies)])
            if not np.array_equal(alone.view(np.uint32), stacked._actions(probe).view(np.uint32)):
                return None
        return stacked

    def _actions(self, x: np.ndarray) -> np.ndarray:
        """The clipped deterministic actions (S * n, *act_shape) of normalised rows x (S * n, obs_dim) float32."""
        torch = _torch()

        h = torch.as_tensor(x).float().reshape(len(self.policies), self.n, self.obs_dim)
        if self._rows:
            for w, b in self._hidden:
                h = self._act(torch.baddbmm(b, h, w))
            out = torch.baddbmm(self._head[1], h, self._head[0])
        else:
            for w, b in self._hidden:
                h = self._act(torch.baddbmm(b, w, h.transpose(1, 2)).transpose(1, 2).contiguous())
            out = torch.cat([torch.nn.functional.linear(h[i], w, b) for i, (w, b) in enumerate(self._head)])
        out = out.reshape(-1, *self.act_shape)
        if self._squashed:  # as SafePolicy._squashed_action
            a = torch.tanh(out).numpy()
            return self.policies[0]._clip_action(self.policies[0]._unscale(a))
        return self.policies[0]._clip_action(out.numpy())

    def predict(self, observation: np.ndarray) -> np.ndarray:
        """The policies' deterministic actions (S * n, *act_shape) for raw observations (S * n, obs_dim), each policy
        normalising its own rows."""
        obs = np.asarray(observation)
        if obs.shape != self._x.shape:
            raise ValueError(f"observation must have shape {self._x.shape} for {len(self.policies)} policies of "
                             f"{self.n} rows, got {obs.shape}")
        if not self._norm:
            return self._actions(obs)
        rows = obs if obs.dtype in (np.float32, np.float64) else obs.astype(np.float64)
        n = self.n
        for i, p in enumerate(self.policies):
            normalize_into(rows[i * n:(i + 1) * n], p._mean, p._std, p._clip, self._x[i * n:(i + 1) * n])
        return self._actions(self._x)


def _read_config(js_path: str) -> dict:
    try:
        with open(js_path, encoding="utf-8") as f:
            cfg = json.load(f, parse_constant=lambda c: (_ for _ in ()).throw(ValueError(f"non-finite {c}")))
    except (ValueError, UnicodeDecodeError) as exc:
        raise SafeWeightsError(f"{js_path}: not valid JSON ({exc})") from None
    _check_config(cfg, js_path)
    return cfg


def _read_tensors(st_path: str, js_path: str, cfg: dict) -> dict[str, np.ndarray]:
    with open(st_path, "rb") as f:
        blob = f.read()  # hash and parse the same bytes, so the file cannot change in between
    digest = sha256(blob)
    if digest != cfg["sha256"]:
        raise SafeWeightsError(f"{st_path}: SHA-256 {digest} does not match the {cfg['sha256']} recorded in "
                               f"{js_path}; the weights were modified or corrupted, refusing to load")
    try:
        tensors = load(blob)
    except (SafetensorError, ValueError, RuntimeError, TypeError) as exc:  # numpy has no bfloat16: TypeError
        raise SafeWeightsError(f"{st_path}: not a valid safetensors file ({exc})") from None
    want = expected_tensors(cfg)
    missing = sorted(set(want) - set(tensors))
    extra = sorted(set(tensors) - set(want))
    if missing or extra:
        raise SafeWeightsError(f"{st_path}: tensors must be exactly {sorted(want)}; missing {missing}, "
                               f"unexpected {extra}")
    for k, (shape, dtype) in want.items():
        t = tensors[k]
        if tuple(t.shape) != shape or t.dtype != np.dtype(dtype):
            raise SafeWeightsError(f"{st_path}: tensor {k!r} must have shape {shape} and dtype {dtype}, got "
                                   f"{tuple(t.shape)} {t.dtype.name}")
        if not np.isfinite(t).all():
            raise SafeWeightsError(f"{st_path}: tensor {k!r} contains non-finite values")
    if "obs_var" in tensors and (tensors["obs_var"] < 0).any():
        raise SafeWeightsError(f"{st_path}: obs_var must be >= 0")
    return {k: np.array(t, order="C") for k, t in tensors.items()}  # own, writable copies (torch.from_numpy)


def load_policy(path) -> SafePolicy:
    """Load ``path.safetensors`` + ``path.json`` without unpickling and without torch (see the module docstring).

    Args:
        path: the model stem ``.../<name>`` (or either of its two files).

    Raises:
        SafeWeightsError (a ValueError): a missing file, a hash mismatch, missing/extra/misshaped tensors,
            non-finite values or a malformed JSON config; the message names the file and the problem.
    """
    st_path, js_path = model_paths(path)
    for p in (js_path, st_path):
        if not os.path.isfile(p):
            raise SafeWeightsError(f"model file {p} not found (a model is PATH.safetensors + PATH.json)")
    cfg = _read_config(js_path)
    tensors = _read_tensors(st_path, js_path, cfg)
    obs_space = _box_from_json(cfg["observation_space"], "observation_space")
    act_space = _box_from_json(cfg["action_space"], "action_space")
    arch = cfg["architecture"]
    if obs_space.shape != (arch["obs_dim"],) or act_space.shape != (arch["act_dim"],):
        raise SafeWeightsError(f"{js_path}: spaces {obs_space.shape}/{act_space.shape} do not match the "
                               f"architecture obs_dim={arch['obs_dim']}, act_dim={arch['act_dim']}")
    return SafePolicy(name=cfg["name"], observation_space=obs_space, action_space=act_space, env_id=cfg["env_id"],
                      env_kwargs=in_legacy_loop(cfg["env_kwargs"]) if cfg["env_id"] == ENV_ID else cfg["env_kwargs"],
                      metadata=cfg["metadata"],
                      obs_normalization=cfg["obs_normalization"], path=js_path, tensors=tensors,
                      activation=arch["activation"], head=arch.get("head"))


def shipped_models() -> dict[str, str]:
    """Name -> stem path of every model shipped in ``ehss_gym/models`` (JSON + safetensors pairs)."""
    folder = MODELS_DIR
    out = {}
    if os.path.isdir(folder):
        for fn in sorted(os.listdir(folder)):
            if fn.endswith(".json") and os.path.isfile(os.path.join(folder, fn[:-5] + ".safetensors")):
                out[fn[:-5]] = os.path.join(folder, fn[:-5])
    return out


__all__ = ["FORMAT", "ACTIVATIONS", "HEADS", "LOG_STD_RANGE", "SafeWeightsError", "SafePolicy", "StackedPolicies",
           "load_policy", "expected_tensors", "model_paths", "sha256", "shipped_models"]
