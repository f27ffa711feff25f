"""The env's ``rgb_array`` dashboard (matplotlib, Agg: no screen needed)."""

from __future__ import annotations

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ehss_gym.core.settings import UNITS, Scenario

from .config import EnvConfig


def current_limits(u: np.ndarray, limit: float | None) -> tuple[float, float]:
    """The y-range of a current panel [mA]: the limit with a margin, or the data's range if unlimited."""
    if limit is not None:
        return -1.15 * limit, 1.15 * limit
    fin = np.abs(u[np.isfinite(u)])
    top = float(fin.max()) if fin.size else 1.0
    return -1.1 * max(top, 1e-9), 1.1 * max(top, 1e-9)


def dashboard_figure(c: dict, cfg: EnvConfig, sc: Scenario | None, size=(6.4, 6.4), dpi=80) -> Figure:
    """The four-panel dashboard of what the env recorded, one value per agent step in each array of ``c``: t [s],
    y, y_ref, r, e [output unit], u_applied, u_base, u_residual, u_min, u_max [mA], friction [N*m]
    (:data:`ehss_gym.envs.env.HIST_COLUMNS`).

    Panels: raw reference r, filtered reference y_d and output y; error e; the applied current on a linear axis
    with its min/max envelope over each agent step (the valve current switches at up to the control rate, far
    faster than one sample per step shows) and the +-current limit; friction torque.
    """
    unit = UNITS[cfg.task]
    fig = Figure(figsize=size, dpi=dpi)
    FigureCanvasAgg(fig)
    ax = fig.subplots(4, 1, sharex=True)
    t = c["t"]
    ax[0].plot(t, c["r"], color="0.55", ls=":", lw=1, label="reference r (raw)")
    ax[0].plot(t, c["y_ref"], "k--", lw=1, label="y_d (filtered)")
    ax[0].plot(t, c["y"], lw=1, label="output y")
    ax[0].set_ylabel(unit)
    ax[0].legend(loc="upper right", fontsize=6)
    ax[1].plot(t, c["e"], lw=0.8)
    ax[1].set_ylabel(f"error [{unit}]")
    ax[2].fill_between(t, c["u_min"], c["u_max"], color="C0", alpha=0.3, lw=0, label="applied (min/max)")
    for edge in (c["u_min"], c["u_max"]):  # a line where the current hardly moves within a step
        ax[2].plot(t, edge, color="C0", lw=0.6)
    ax[2].plot(t, c["u_residual"], color="C2", lw=0.6, label="residual")
    if cfg.current_limit is not None:
        for sgn in (-1.0, 1.0):
            ax[2].axhline(sgn * cfg.current_limit, color="r", lw=0.7, ls="--")
    ax[2].set_ylim(*current_limits(np.concatenate([c["u_min"], c["u_max"]]), cfg.current_limit))
    ax[2].set_ylabel("u [mA]")
    ax[2].legend(loc="upper right", fontsize=6)
    peak = float(np.max(np.abs(c["u_base"]))) if len(t) else 0.0
    ax[2].set_title(f"base-law command peak {peak:.3g} mA" + (" (limit dashed)" if cfg.current_limit else ""),
                    fontsize=7, loc="left")
    ax[3].plot(t, c["friction"], lw=1)
    ax[3].set_ylabel("friction [N m]")
    ax[3].set_xlabel("time [s]")
    name = sc.reference.description if sc is not None else ""
    fig.suptitle(f"EHSSTracking-v0 {cfg.task}/{cfg.mode}, n={cfg.n}  {name}", fontsize=8)
    fig.tight_layout()
    return fig


def render_dashboard(c: dict, cfg: EnvConfig, sc: Scenario | None, size=(6.4, 6.4), dpi=80) -> np.ndarray:
    """The dashboard (:func:`dashboard_figure`) as an (H, W, 3) uint8 RGB image."""
    fig = dashboard_figure(c, cfg, sc, size, dpi)
    fig.canvas.draw()
    return np.asarray(fig.canvas.buffer_rgba())[:, :, :3].copy()
