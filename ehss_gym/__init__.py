"""ehss-gym: the EHSS servo loop of Mintsa et al. with Sontag/CLF controllers, as a fast,
verified simulator and a Gymnasium environment.

Quick start::

    from . import Scenario, simulate
    traj = simulate(Scenario(task="velocity", n=2, fr=100.0, current_limit=10.0, t_end=20.0))
    print(traj.metrics()["rmse"])
"""

from ._version import __version__
from .core.params import PlantParams, make_plant_params
from .core.signals import Reference, chirp, from_array, from_function, multisine, paper_reference, sine, step
from .core.sim import PAPER_FRICTION, TASKS, Scenario, Trajectory, simulate, simulate_batch

__all__ = [
    "PlantParams",
    "make_plant_params",
    "Reference",
    "sine",
    "step",
    "chirp",
    "multisine",
    "from_array",
    "from_function",
    "paper_reference",
    "Scenario",
    "Trajectory",
    "simulate",
    "simulate_batch",
    "PAPER_FRICTION",
    "TASKS",
    "__version__",
]
from . import envs  # noqa: E402,F401  (registers EHSSTracking-v0 with Gymnasium)
