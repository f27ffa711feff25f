"""The env's ``rgb_array`` dashboard (matplotlib, Agg: no screen needed)."""

from __future__ import annotations

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ehss_gym.core.sim import UNITS, Scenario

from .config import EnvConfig


def render_dashboard(h: np.ndarray, cfg: EnvConfig, sc: Scenario | None, size=(6.4, 6.4), dpi=80) -> np.ndarray:
    """Draw (t, y, y_d, e, u_applied, u_base, u_res, friction) rows as a four-panel RGB image."""
    unit = UNITS[cfg.task]
    fig = Figure(figsize=size, dpi=dpi)
    canvas = FigureCanvasAgg(fig)
    ax = fig.subplots(4, 1, sharex=True)
    t = h[:, 0]
    ax[0].plot(t, h[:, 2], "k--", lw=1, label="reference")
    ax[0].plot(t, h[:, 1], lw=1, label="output")
    ax[0].set_ylabel(unit)
    ax[0].legend(loc="upper right", fontsize=7)
    ax[1].plot(t, h[:, 3], lw=0.8)
    ax[1].set_ylabel(f"error [{unit}]")
    ax[2].plot(t, h[:, 4], lw=0.8, label="applied")
    ax[2].plot(t, h[:, 5], lw=0.6, label="base law")
    ax[2].plot(t, h[:, 6], lw=0.6, label="residual")
    ax[2].set_ylabel("u [mA]")
    ax[2].legend(loc="upper right", fontsize=7)
    ax[3].plot(t, h[:, 7], lw=1)
    ax[3].set_ylabel("friction [N m]")
    ax[3].set_xlabel("time [s]")
    name = sc.reference.description if sc is not None else ""
    fig.suptitle(f"EHSSTracking-v0 {cfg.task}/{cfg.mode}, n={cfg.n}  {name}", fontsize=8)
    fig.tight_layout()
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[:, :, :3].copy()
