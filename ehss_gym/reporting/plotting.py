"""Figures of closed-loop runs (matplotlib, Agg backend: no screen needed); public as :mod:`ehss_gym.plotting`."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from ehss_gym.core.sim import UNITS  # noqa: E402


def _title(traj) -> str:
    sc = traj.scenario
    lim = "none" if sc.current_limit is None else f"{sc.current_limit:g} mA"
    return (f"{sc.task}, n={sc.n}, f_r={sc.fr:g} Hz, sigma={sc.sigma:g}, w={sc.smoothing:g}, "
            f"h={sc.control_period:g} s, limit={lim}; {sc.reference.description}")


def _current_panel(ax, traj) -> None:
    """The applied current on a linear axis: its min/max envelope over each log interval (not the aliased samples)
    and the +-limit; the commanded (unlimited) current only as numbers in the title (its spikes would hide the rest)."""
    sc = traj.scenario
    t = traj.t
    lo, hi = traj.u_applied_min, traj.u_applied_max
    ax.fill_between(t, lo, hi, color="C0", alpha=0.35, lw=0, label="applied: min/max per log interval")
    for edge in (lo, hi):  # the envelope's edges: a line where the current hardly moves within an interval
        ax.plot(t, edge, color="C0", lw=0.6)
    if sc.current_limit is not None:
        for sgn in (-1.0, 1.0):
            ax.axhline(sgn * sc.current_limit, color="r", lw=0.8, ls="--",
                       label="current limit" if sgn > 0 else None)
        ax.set_ylim(-1.15 * sc.current_limit, 1.15 * sc.current_limit)
    m = traj.metrics()
    ax.set_title(f"commanded peak {m['peak_u']:.3g} mA, at the limit on {m['saturation']:.1%} of control steps",
                 fontsize=8, loc="left")
    ax.set_ylabel("applied u [mA]")
    ax.legend(loc="upper right", fontsize=7)


def trajectory_figure(traj, title: str | None = None, made_by: str | None = None):
    """The figure of a run: four stacked panels sharing the time axis [s].

    1. the raw reference r, the reference model's output y_d (the filtered reference the loop tracks) and the
       output y [output unit];
    2. the tracking error e = y - y_d;
    3. the applied current [mA] on a linear axis, with its min/max envelope over each log interval (the valve
       current switches at up to the control rate, far faster than the log samples, which would alias it), the
       +-current limit and,
       in the panel's title, the commanded peak and the share of steps at the limit;
    4. the friction torque [N*m].

    Args:
        traj: a :class:`~ehss_gym.core.sim.Trajectory`.
        title: figure title (default: the scenario's main settings).
        made_by: the command that made the figure, printed in the footer.

    Returns:
        The matplotlib Figure (close it with ``matplotlib.pyplot.close``).
    """
    sc = traj.scenario
    unit = UNITS[sc.task]
    t = traj.t
    fig, ax = plt.subplots(4, 1, figsize=(9, 9.5), sharex=True)
    ax[0].plot(t, traj.r, color="0.55", ls=":", lw=1.2, label="reference r (raw)")
    ax[0].plot(t, traj.y_ref, "k--", lw=1, label="$y_d$ (reference model)")
    ax[0].plot(t, traj.y, lw=1, label="output $y$")
    ax[0].set_ylabel(f"{sc.task} [{unit}]")
    ax[0].legend(loc="upper right", fontsize=8)
    ax[1].plot(t, traj.e, lw=0.8)
    ax[1].set_ylabel(f"error $e$ [{unit}]")
    _current_panel(ax[2], traj)
    ax[3].plot(t, traj.friction, lw=1)
    ax[3].set_ylabel("friction [N m]")
    ax[3].set_xlabel("time [s]")
    ttl = title or _title(traj)
    if traj.diverged:
        ttl += f"\nDIVERGED at t={traj.t_diverged:.4g} s ({traj.divergence_reason})"
        for a in ax:
            a.axvline(traj.t_diverged, color="r", lw=1)
    elif traj.lost_track:
        ttl += f"\nLOST TRACK at t={traj.metrics()['t_lost_track']:.4g} s"
    fig.suptitle(ttl, fontsize=10)
    if made_by:
        fig.text(0.01, 0.005, f"made by: {made_by}", fontsize=7, color="gray")
    fig.tight_layout(rect=(0, 0.015, 1, 1))
    return fig


def plot_trajectory(traj, path, title: str | None = None, made_by: str | None = None) -> str:
    """Write the figure of a run (:func:`trajectory_figure`) as a PNG.

    Args:
        traj: a :class:`~ehss_gym.core.sim.Trajectory`.
        path: PNG file to write.
        title: figure title (default: the scenario's main settings).
        made_by: the command that made the figure, printed in the footer.

    Returns:
        ``path``.
    """
    fig = trajectory_figure(traj, title, made_by)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return str(path)
