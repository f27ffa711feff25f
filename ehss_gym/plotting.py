"""Figures of closed-loop runs: the public home of the plotting functions
(:mod:`ehss_gym.reporting.trajectory_figures`).

Example::

    from ehss_gym import simulate
    from ehss_gym.plotting import plot_trajectory
    plot_trajectory(simulate(sigma=1e5, current_limit=10.0, t_end=2.0), "run.png")
"""

from ehss_gym.reporting.trajectory_figures import (
    frequency_response_figure,
    plot_frequency_response,
    plot_trajectory,
    trajectory_figure,
)

__all__ = ["plot_trajectory", "trajectory_figure", "plot_frequency_response", "frequency_response_figure"]
