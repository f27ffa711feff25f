"""Figures of closed-loop runs (matplotlib, Agg backend: no screen needed)."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ehss_gym.core.sim import UNITS


def plot_trajectory(traj, path, title: str | None = None, made_by: str | None = None):
    """Four stacked panels: response vs reference, error, control (log scale if it spans decades), friction.

    Args:
        traj: a :class:`~ehss_gym.core.sim.Trajectory`.
        path: PNG file to write.
        title: figure title (default: the scenario's main settings).
        made_by: the command that made the figure, printed in the footer.
    """
    sc = traj.scenario
    unit = UNITS[sc.task]
    t = traj.t
    fig, ax = plt.subplots(4, 1, figsize=(9, 9), sharex=True)
    ax[0].plot(t, traj.y_ref, "k--", lw=1, label="reference $y_d$")
    ax[0].plot(t, traj.y, lw=1, label="output $y$")
    ax[0].set_ylabel(f"{sc.task} [{unit}]")
    ax[0].legend(loc="upper right", fontsize=8)
    ax[1].plot(t, traj.e, lw=0.8)
    ax[1].set_ylabel(f"error $e$ [{unit}]")
    u = traj.u
    ua = traj.u_applied
    au = np.abs(u[np.isfinite(u)])
    if au.size and au.max() > 0 and au.max() / max(np.percentile(au, 50), 1e-12) > 1e3:
        ax[2].semilogy(t, np.maximum(np.abs(u), 1e-12), lw=0.6, label="|u| commanded")
        ax[2].semilogy(t, np.maximum(np.abs(ua), 1e-12), lw=0.6, label="|u| applied")
        ax[2].set_ylabel("|u| [mA] (log)")
    else:
        ax[2].plot(t, u, lw=0.6, label="commanded")
        ax[2].plot(t, ua, lw=0.6, label="applied")
        ax[2].set_ylabel("u [mA]")
    ax[2].legend(loc="upper right", fontsize=8)
    ax[3].plot(t, traj.friction, lw=1)
    ax[3].set_ylabel("friction [N m]")
    ax[3].set_xlabel("time [s]")
    lim = "none" if sc.current_limit is None else f"{sc.current_limit:g} mA"
    ttl = title or (f"{sc.task}, n={sc.n}, f_r={sc.fr:g} Hz, sigma={sc.sigma:g}, w={sc.smoothing:g}, "
                    f"h={sc.control_period:g} s, limit={lim}")
    if traj.diverged:
        ttl += f"\nDIVERGED at t={traj.t_diverged:.4g} s ({traj.divergence_reason})"
        for a in ax:
            a.axvline(traj.t_diverged, color="r", lw=1)
    fig.suptitle(ttl, fontsize=10)
    if made_by:
        fig.text(0.01, 0.005, f"made by: {made_by}", fontsize=7, color="gray")
    fig.tight_layout(rect=(0, 0.015, 1, 1))
    fig.savefig(path, dpi=90)
    plt.close(fig)
