"""ehss-gym: the EHSS servo loop of Mintsa et al. with Sontag/CLF controllers, as a fast,
verified simulator and a Gymnasium environment.

Quick start::

    from ehss_gym import Scenario, simulate
    traj = simulate(Scenario(task="velocity", n=2, fr=100.0, current_limit=10.0, t_end=20.0))
    print(traj.metrics()["rmse"])

Importing the package is cheap: its names load on first use (the simulator's kernels need numba, the env Gymnasium),
and ``EHSSTracking-v0`` is registered with Gymnasium as soon as Gymnasium is imported (at once if it already is), so
``import ehss_gym`` followed by ``gymnasium.make("EHSSTracking-v0")`` works, as does
``gymnasium.make("ehss_gym:EHSSTracking-v0")``.
"""

from ._version import __version__
from .envs import register_on_import
from .infra.lazy import lazy_exports

_EXPORTS = {
    "PlantParams": ".core.params", "make_plant_params": ".core.params",
    "Rig": ".core.rig", "load_rig": ".core.rig", "as_rig": ".core.rig",
    "Reference": ".core.signals", "sine": ".core.signals", "step": ".core.signals", "chirp": ".core.signals",
    "multisine": ".core.signals", "from_array": ".core.signals", "from_function": ".core.signals",
    "paper_reference": ".core.signals",
    "Scenario": ".core.settings", "PAPER_FRICTION": ".core.settings", "TASKS": ".core.settings",
    "Trajectory": ".core.sim", "simulate": ".core.sim", "simulate_batch": ".core.sim",
    "Unmodelled": ".core.unmodelled",
}
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
__all__ = [*_EXPORTS, "__version__"]

register_on_import()
