"""The noise study's figures: heat maps of noise level x (estimator, law), the spread over n, the sensor channels."""

from __future__ import annotations

import math

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ehss_gym.core.settings import UNITS  # noqa: E402

MAP_METRICS = (("rmse_quiet", "quiet RMSE (true error)", True), ("fric", "peak |e| in friction", True),
               ("tv", "control TV [mA/s]", True), ("sat", "saturation (share of steps)", False),
               ("lost", "lost share", False))


def _made_by(fig, cmd: str) -> None:
    fig.text(0.005, 0.003, f"made by: {cmd}", fontsize=7, color="gray")


def _panel(ax, M: np.ndarray, rows, cols, title: str, log: bool, fmt: str = ".2g") -> None:
    V = np.where(np.isfinite(M) & (M > 0), np.log10(np.where(M > 0, M, 1.0)), np.nan) if log else M
    im = ax.imshow(V, aspect="auto", cmap="viridis")
    plt.colorbar(im, ax=ax, fraction=0.02, pad=0.01, label="log10" if log else None)
    for i in range(M.shape[0]):
        for j in range(M.shape[1]):
            v = M[i, j]
            txt = "n/a" if not math.isfinite(v) else format(v, fmt)
            ax.text(j, i, txt, ha="center", va="center", fontsize=5.5, color="w")
    ax.set_xticks(range(len(cols)))
    ax.set_xticklabels(cols, rotation=60, ha="right", fontsize=7)
    ax.set_yticks(range(len(rows)))
    ax.set_yticklabels(rows, fontsize=7)
    ax.set_title(title, fontsize=9)


def plot_noise_maps(cells: dict, rows: list, pairs: list, task: str, n: int, path: str, cmd: str) -> None:
    """One panel per metric: rows = noise rows, columns = (estimator, law) pairs, medians over the cell's episodes.

    Args:
        cells: (estimator, law) -> row -> summary (:func:`ehss_gym.study.noise_rules.summary`).
    """
    cols = [f"{e} / {lw}" for e, lw in pairs]
    fig, axs = plt.subplots(len(MAP_METRICS), 1, figsize=(14, 3.0 * len(MAP_METRICS)))
    for ax, (key, label, log) in zip(axs, MAP_METRICS):
        M = np.array([[cells[p][r][key] for p in pairs] for r in rows], dtype=float)
        unit = f" [{UNITS[task]}]" if key in ("rmse_quiet", "fric") else ""
        _panel(ax, M, rows, cols, f"{task}, n = {n}: {label}{unit}", log)
    fig.suptitle(f"Noise study, {task} task: noise level (multiples of the env's largest noise; 'realistic' = the "
                 f"named sensor set) x estimator / law", fontsize=10)
    _made_by(fig, cmd)
    fig.tight_layout(rect=(0, 0.01, 1, 0.98))
    fig.savefig(path, dpi=85)
    plt.close(fig)


def plot_n_spread(spread: dict, rows: list, pairs: list, task: str, path: str, cmd: str) -> None:
    """max/min over n = 2, 4, 6 of quiet RMSE, friction peak and TV per cell (1 = n changes nothing)."""
    cols = [f"{e} / {lw}" for e, lw in pairs]
    keys = (("rmse_quiet", "quiet RMSE"), ("fric", "peak |e| in friction"), ("tv", "control TV"))
    fig, axs = plt.subplots(len(keys), 1, figsize=(14, 3.0 * len(keys)))
    for ax, (key, label) in zip(axs, keys):
        M = np.array([[spread[(p, r)][key] for p in pairs] for r in rows], dtype=float)
        _panel(ax, M, rows, cols, f"{task}: spread over n (max/min over n = 2, 4, 6) of the {label}", False)
    _made_by(fig, cmd)
    fig.tight_layout(rect=(0, 0.01, 1, 1))
    fig.savefig(path, dpi=85)
    plt.close(fig)


def plot_channels(chan: dict, estimators: list, rows: list, path: str, cmd: str) -> None:
    """Median control TV with the noise on one sensor channel only, per estimator (n = 2, Sontag)."""
    names = ("x1 position", "x2 velocity", "x3 pressure", "x4 valve")
    fig, axs = plt.subplots(2, len(rows), figsize=(6 * len(rows), 7), squeeze=False)
    for i, task in enumerate(("velocity", "position")):
        for j, row in enumerate(rows):
            ax = axs[i, j]
            x = np.arange(len(estimators))
            for c in range(4):
                v = [chan[(task, e, c, row)] for e in estimators]
                ax.bar(x + (c - 1.5) * 0.2, v, width=0.2, label=names[c])
            ax.set_yscale("log")
            ax.set_xticks(x)
            ax.set_xticklabels(estimators, fontsize=8)
            ax.set_ylabel("median control TV [mA/s]")
            ax.set_title(f"{task}, noise {row} on one channel", fontsize=9)
            if i == 0 and j == 0:
                ax.legend(fontsize=7)
    _made_by(fig, cmd)
    fig.tight_layout(rect=(0, 0.02, 1, 1))
    fig.savefig(path, dpi=85)
    plt.close(fig)


def plot_step(trajs: list, labels: list, path: str, cmd: str, title: str) -> None:
    """The output, the reference model's output and the current of one episode under several loops."""
    fig, axs = plt.subplots(len(trajs), 2, figsize=(12, 2.6 * len(trajs)), squeeze=False)
    for k, (tr, lab) in enumerate(zip(trajs, labels)):
        ax = axs[k, 0]
        ax.plot(tr.t, tr.r, "k:", lw=1, label="r")
        ax.plot(tr.t, tr.y_ref, "k--", lw=1, label="y_d")
        ax.plot(tr.t, tr.y, lw=1, label="y")
        ax.set_ylabel(f"[{UNITS[tr.scenario.task]}]")
        ax.set_title(lab, fontsize=9)
        ax.legend(fontsize=7, loc="upper right")
        axs[k, 1].plot(tr.t, tr.u_applied, lw=0.6)
        axs[k, 1].set_ylabel("u applied [mA]")
    axs[-1, 0].set_xlabel("time [s]")
    axs[-1, 1].set_xlabel("time [s]")
    fig.suptitle(title, fontsize=10)
    _made_by(fig, cmd)
    fig.tight_layout(rect=(0, 0.02, 1, 0.97))
    fig.savefig(path, dpi=85)
    plt.close(fig)
