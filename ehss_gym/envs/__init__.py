"""``EHSSTracking-v0``: the single env, the native vector env, their configuration and the one rollout loop.

``import ehss_gym`` registers ``EHSSTracking-v0`` with Gymnasium when Gymnasium is imported (at once if it already
is; :func:`register_on_import`). Gymnasium 1.x loads no plugin entry points, so in a fresh interpreter either import
``ehss_gym`` first or use Gymnasium's ``"module:EnvId"`` form, ``gymnasium.make("ehss_gym:EHSSTracking-v0")``, which
imports it. The names below load on first use.
"""

from __future__ import annotations

import importlib.util
import sys

from ehss_gym.infra.lazy import lazy_exports

ENV_ID = "EHSSTracking-v0"

_EXPORTS = {
    "DEFAULTS": ".config", "EnvConfig": ".config", "EnvDefaults": ".config", "TaskDefaults": ".config",
    "EHSSTrackingEnv": ".env", "EHSSTrackingVectorEnv": ".vector", "OBS_BOUND": ".observation",
    "decode_observation": ".observation", "observation_layout": ".observation", "symlog_inverse": ".observation",
    "rollout": ".rollouts", "EpisodeResult": ".rollouts",
}
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)


def register_envs() -> None:
    """Register ``EHSSTracking-v0`` and its vector entry point with Gymnasium (idempotent)."""
    import gymnasium as gym  # 0.2-0.7 s: only when Gymnasium is (being) imported anyway, see register_on_import

    if ENV_ID not in gym.registry:
        gym.register(ENV_ID, entry_point="ehss_gym.envs.env:EHSSTrackingEnv",
                     vector_entry_point="ehss_gym.envs.vector:EHSSTrackingVectorEnv")


class _AfterImport:
    """Gymnasium's own loader, which registers the env once it has executed the module (a loader by its methods:
    importlib.abc would cost the command line 0.1 s)."""

    def __init__(self, loader):
        self._loader = loader

    def create_module(self, spec):
        return self._loader.create_module(spec)

    def exec_module(self, module) -> None:
        self._loader.exec_module(module)
        register_envs()

    def __getattr__(self, name):  # everything else (resources, source) is the wrapped loader's
        return getattr(self._loader, name)


class _OnGymnasiumImport:
    """Finds ``gymnasium`` the usual way, once, and has its loader register the env after executing it."""

    def find_spec(self, fullname, path=None, target=None):
        if fullname != "gymnasium":
            return None
        sys.meta_path.remove(self)
        spec = importlib.util.find_spec(fullname)
        if spec is not None and spec.loader is not None:
            spec.loader = _AfterImport(spec.loader)
        return spec


def register_on_import() -> None:
    """Register the env now if Gymnasium is imported, else right after it is (``import ehss_gym`` calls this):
    the command line and the simulator never pay for Gymnasium, and users of the env do not notice."""
    if "gymnasium" in sys.modules:
        register_envs()
    elif not any(isinstance(f, _OnGymnasiumImport) for f in sys.meta_path):
        sys.meta_path.insert(0, _OnGymnasiumImport())


__all__ = ["ENV_ID", *_EXPORTS, "register_envs", "register_on_import"]
