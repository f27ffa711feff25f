"""Figures of the reproduction study (each says which command made it)."""

from __future__ import annotations

import math
import multiprocessing as mp
from collections.abc import Sequence

import numpy as np
from matplotlib import colors
from matplotlib.ticker import LogLocator, NullLocator

from ehss_gym._version import __version__
from ehss_gym.core.settings import UNITS
from ehss_gym.infra.fmt import fmt_axis
from ehss_gym.study.config import NS
from ehss_gym.study.records import Record
from ehss_gym.study.rules import MAP_METRICS, cells_of, n_effect

from .trajectory_figures import plt


def _made_by(cmd: str) -> str:
    return f"made by: {cmd}  (ehss-gym {__version__})"


def _env(t: np.ndarray, y: np.ndarray, bins: int = 1500) -> tuple[np.ndarray, np.ndarray]:
    """Min/max envelope per time bin: a few thousand points that draw like the full signal at figure size."""
    n = len(t)
    if n <= 2 * bins:
        return t, y
    k = n // bins
    m = k * bins
    yb = y[:m].reshape(bins, k)
    tb = t[:m].reshape(bins, k)[:, 0]
    lo, hi = yb.min(axis=1), yb.max(axis=1)
    tt = np.repeat(tb, 2)
    yy = np.empty(2 * bins)
    yy[0::2], yy[1::2] = lo, hi
    return np.concatenate([tt, t[m:]]), np.concatenate([yy, y[m:]])


def plot_paper_set(recs: Sequence[Record], task: str, fr: float | None, path: str, title: str, cmd: str):
    """Figs. 5-13 in one: columns n = 2, 4, 6; rows friction, response vs reference, error, control (the runs of
    ``task`` at ``fr`` [Hz]; None: at any f_r)."""

    by_n = {r.params["n"]: r for r in recs if r.params["task"] == task and fr in (None, r.params["fr"])}
    fig, ax = plt.subplots(4, 3, figsize=(14, 10), sharex="col")
    unit = UNITS[task]
    for j, n in enumerate(NS):
        r = by_n.get(n)
        if r is None:
            continue
        tr = r.traj
        t = tr.t
        a = ax[:, j]
        a[0].plot(*_env(t, tr.friction), lw=1, color="C3")
        a[1].plot(*_env(t, tr.y_ref), "k--", lw=1, label="reference y_d")
        a[1].plot(*_env(t, tr.y), lw=0.8, label="output y")
        a[2].plot(*_env(t, tr.e), lw=0.6)
        u, ua = np.abs(tr.u), np.abs(tr.u_applied)
        fin = u[np.isfinite(u) & (u > 0)]
        if fin.size and fin.max() / max(np.percentile(fin, 50), 1e-12) > 1e3 or (fin.size and fin.max() > 1e4):
            a[3].semilogy(*_env(t, np.maximum(u, 1e-6)), lw=0.5, label="|u| commanded")
            a[3].semilogy(*_env(t, np.maximum(ua, 1e-6)), lw=0.5, label="|u| applied")
            a[3].yaxis.set_major_locator(LogLocator(numticks=6))
            a[3].yaxis.set_minor_locator(NullLocator())
            a[3].set_ylabel("|u| [mA] (log)" if j == 0 else "")
        else:
            a[3].plot(*_env(t, tr.u), lw=0.5, label="u commanded")
            a[3].plot(*_env(t, tr.u_applied), lw=0.5, label="u applied")
            a[3].set_ylabel("u [mA]" if j == 0 else "")
        m = r.metrics
        head = f"n = {n}"
        if m["diverged"]:
            head += f"\nDIVERGED at t = {m['t_diverged']:.4g} s ({m['divergence_reason']})"
            for x in a:
                x.axvline(m["t_diverged"], color="r", lw=1)
            if len(t) < 3:
                a[1].text(0.5, 0.5, f"diverged at t = {m['t_diverged']:.3g} s\n(no plottable history)",
                          transform=a[1].transAxes, ha="center", color="r")
        else:
            head += (f"\nRMSE {m['rmse']:.2e}, peak in friction {m['max_abs_e_friction']:.2e} {unit},"
                     f" sat {m['saturation']:.1%}")
        a[0].set_title(head, fontsize=9, color="r" if m["diverged"] else "k")
        a[3].set_xlabel("time [s]")
        if j == 0:
            a[0].set_ylabel("friction [N m]")
            a[1].set_ylabel(f"{task} [{unit}]")
            a[2].set_ylabel(f"error [{unit}]")
        if j == 0:  # one legend per row is enough (legends cost a lot of drawing time)
            a[1].legend(loc="upper right", fontsize=7)
            a[3].legend(loc="upper right", fontsize=7)
    fig.suptitle(title, fontsize=10)
    fig.text(0.01, 0.003, _made_by(cmd), fontsize=7, color="gray")
    # fixed margins: tight_layout costs seconds per figure on these log axes
    fig.subplots_adjust(left=0.06, right=0.99, bottom=0.06, top=0.88, wspace=0.18, hspace=0.12)
    fig.savefig(path, dpi=72)
    plt.close(fig)


def plot_divergence(recs: Sequence[Record], path: str, cmd: str):
    """The unlimited paper law (P0): |u| and |e| up to divergence, every run."""
    fig, ax = plt.subplots(1, 2, figsize=(12, 4.2))
    for i, r in enumerate(recs):
        tr = r.traj
        lab = f"{r.params['task'][:3]} {r.params['fr']:g} Hz n={r.params['n']}"
        c = f"C{i % 10}"
        if len(tr.t):
            ax[0].semilogy(tr.t * 1e3, np.maximum(np.abs(tr.u), 1e-12), lw=1, color=c, marker=".", ms=3, label=lab)
            ax[1].semilogy(tr.t * 1e3, np.maximum(np.abs(tr.e), 1e-18), lw=1, color=c, marker=".", ms=3)
        if r.metrics["diverged"]:
            for a in ax:
                a.axvline(r.metrics["t_diverged"] * 1e3, color=c, lw=0.8, ls=":")
    ax[0].set_ylabel("|u| commanded [mA]")
    ax[1].set_ylabel("|e| [output unit]")
    for a in ax:
        a.set_xlabel("time [ms]  (dotted: divergence time)")
    ax[0].legend(fontsize=6, ncol=2)
    tds = [r.metrics["t_diverged"] for r in recs if r.metrics["diverged"]]
    fig.suptitle(f"Paper law as printed (sigma=1, no current limit), h = {recs[0].params['h']:g} s: "
                 f"{len(tds)}/{len(recs)} runs diverge, all by t = {max(tds) if tds else float('nan'):.3g} s",
                 fontsize=10)
    fig.text(0.01, 0.003, _made_by(cmd), fontsize=7, color="gray")
    fig.tight_layout(rect=(0, 0.03, 1, 0.95))
    fig.savefig(path, dpi=80)
    plt.close(fig)


def plot_sweep_maps(records: Sequence[Record], row: str, col: str, path: str, title: str, cmd: str,
                    row_label: str, col_label: str, starred: Sequence = ()):
    """Per-n heat maps of the outcome metrics plus a column for the spread over n.

    Diverged cells are black with 'D'; cells not run are light grey.
    """

    cells = cells_of(records, row, col)
    rows = sorted({k[0] for k in cells}, key=lambda v: (v is not None, v if v is not None else 0))
    cols = sorted({k[1] for k in cells}, key=lambda v: (v is not None, v if v is not None else 0))
    nm = len(MAP_METRICS)
    fig, ax = plt.subplots(nm, 4, figsize=(4 + 1.0 * len(cols) * 2.2, 2.0 + 0.34 * len(rows) * nm),
                           squeeze=False)
    for i, (key, label, logscale) in enumerate(MAP_METRICS):
        norm = _metric_norm(cells, key, logscale)
        for j, n in enumerate(NS):
            _map_panel(ax[i, j], cells, rows, cols, n, key, norm, logscale)
            ax[i, j].set_title(f"n = {n}: {label}", fontsize=8)
            _ticks(ax[i, j], rows, cols, row_label if j == 0 else "", col_label, starred)
        _spread_panel(ax[i, 3], cells, rows, cols, key)
        _ticks(ax[i, 3], rows, cols, "", col_label, starred)
    fig.suptitle(title, fontsize=10)
    fig.text(0.01, 0.003, _made_by(cmd), fontsize=7, color="gray")
    fig.tight_layout(rect=(0, 0.012, 1, 0.985))
    fig.savefig(path, dpi=75)
    plt.close(fig)


def _metric_norm(cells, key: str, logscale: bool):
    """Colour scale of one metric over every non-diverged run of the map (log: its finite positive range)."""
    vals = [c[n].get(key) for c in cells.values() for n in c if not c[n].get("diverged", False)]
    vals = [v for v in vals if v is not None and math.isfinite(v) and (v > 0 or not logscale)]
    if not logscale:
        return colors.Normalize(vmin=0.0, vmax=1.0)
    lo, hi = (min(vals), max(vals)) if vals else (1e-3, 1.0)
    return colors.LogNorm(vmin=lo, vmax=max(hi, lo * 10))


def _map_panel(axx, cells, rows, cols, n: int, key: str, norm, logscale: bool) -> None:
    """One metric's heat map for one n: values written in the cells, diverged runs black with 'D'."""
    cmap = plt.get_cmap("viridis").copy()
    cmap.set_bad("#dddddd")
    Z = np.full((len(rows), len(cols)), np.nan)
    txt = {}
    for (rv, cv), c in cells.items():
        a, b = rows.index(rv), cols.index(cv)
        r = c.get(n)
        if r is None:
            continue
        if r.get("diverged", False):
            txt[(a, b)] = ("D", "w")
            continue
        v = r.get(key)
        if v is None or not math.isfinite(v):
            txt[(a, b)] = ("inf" if v is not None and math.isinf(v) else "nan", "r")
            continue
        Z[a, b] = max(v, norm.vmin) if logscale else v
        txt[(a, b)] = (f"{v:.1g}" if logscale else f"{v:.2f}", "w")
    axx.imshow(np.ma.masked_invalid(Z), cmap=cmap, norm=norm, aspect="auto", origin="lower")
    for (a, b), (s, colr) in txt.items():
        if s == "D":
            axx.add_patch(plt.Rectangle((b - 0.5, a - 0.5), 1, 1, color="k"))
        axx.text(b, a, s, ha="center", va="center", fontsize=6, color=colr)


def _spread_panel(axx, cells, rows, cols, key: str) -> None:
    """The spread of one metric over n per cell; orange where n matters, red 'D≠' where only some n diverge."""
    Z = np.full((len(rows), len(cols)), np.nan)
    for (rv, cv), c in cells.items():
        if len(c) < 2:
            continue
        a, b = rows.index(rv), cols.index(cv)
        eff = n_effect(c)
        sp, matters = eff[key]
        if eff["diverged"][1]:
            axx.add_patch(plt.Rectangle((b - 0.5, a - 0.5), 1, 1, color="#b2182b"))
            axx.text(b, a, "D≠", ha="center", va="center", fontsize=6, color="w")
            continue
        if eff["diverged"][0] == len(c):
            axx.add_patch(plt.Rectangle((b - 0.5, a - 0.5), 1, 1, color="k"))
            axx.text(b, a, "D", ha="center", va="center", fontsize=6, color="w")
            continue
        if sp is None or math.isnan(sp):
            continue
        Z[a, b] = 1.0 if matters else 0.0
        s = (f"{sp:.2f}" if key == "saturation" else "inf" if math.isinf(sp) else
             (f"{sp:.2f}s" if key == "recovery_on" else f"x{sp:.1f}"))
        axx.text(b, a, s, ha="center", va="center", fontsize=6, color="k")
    axx.imshow(np.ma.masked_invalid(Z), cmap=colors.ListedColormap(["#d9f0d3", "#fdb863"]),
               vmin=0, vmax=1, aspect="auto", origin="lower")
    axx.set_title("spread over n (orange: n matters)", fontsize=8)


def _ticks(axx, rows, cols, row_label, col_label, starred=()):
    axx.set_xticks(range(len(cols)))
    axx.set_xticklabels([fmt_axis(c) + ("*" if c in starred else "") for c in cols], fontsize=6, rotation=45)
    axx.set_yticks(range(len(rows)))
    axx.set_yticklabels([fmt_axis(r) for r in rows], fontsize=6)
    if col_label:
        axx.set_xlabel(col_label, fontsize=7)
    if row_label:
        axx.set_ylabel(row_label, fontsize=7)


def plot_relay(records: Sequence[Record], path: str, cmd: str):
    """Saturation fraction against the relay index beta/limit (all limited sweep runs), per n."""
    fig, ax = plt.subplots(1, 2, figsize=(12, 4.2))
    for n, mk in zip(NS, "os^"):
        rs = [r for r in records if r.params["n"] == n and not r.get("diverged", False)]
        x = [r.get("beta_log_limit") for r in rs]
        y = [r.get("saturation") for r in rs]
        ax[0].scatter(x, y, s=12, marker=mk, alpha=0.6, label=f"n = {n}")
        x2 = [r.get("relay_log_ratio") for r in rs]
        ax[1].scatter(x2, [r.get("tv_u_rate") for r in rs], s=12, marker=mk, alpha=0.6, label=f"n = {n}")
    ax[0].axvline(0, color="k", lw=0.8, ls=":")
    ax[0].set_xlabel("median log10( beta / current limit ),  beta = |s/sigma|^(n-1) |G| / sigma")
    ax[0].set_ylabel("saturation fraction")
    ax[1].axvline(0, color="k", lw=0.8, ls=":")
    ax[1].set_yscale("log")
    ax[1].set_xlabel("median log10( beta / |psi/G| )")
    ax[1].set_ylabel("chattering: control TV rate [mA/s]")
    for a in ax:
        a.legend(fontsize=7)
    fig.suptitle("Relay regime: does the law saturate where its s-dependent term beta exceeds the limit?",
                 fontsize=10)
    fig.text(0.01, 0.003, _made_by(cmd), fontsize=7, color="gray")
    fig.tight_layout(rect=(0, 0.03, 1, 0.95))
    fig.savefig(path, dpi=80)
    plt.close(fig)


def _busiest_window(tr, width: float) -> float:
    """Start [s] of the window (before the first friction event) where the applied current varies most."""
    on = tr.scenario.friction[0][1] if tr.scenario.friction else tr.scenario.t_end
    sel = tr.t < on
    t, u = tr.t[sel], tr.u_applied[sel]
    if len(t) < 3:
        return 0.0
    dt = float(t[1] - t[0])
    k = max(1, int(round(width / dt)))
    tv = np.concatenate([[0.0], np.cumsum(np.abs(np.diff(u)))])
    if len(tv) <= k:
        return float(t[0])
    i = int(np.argmax(tv[k:] - tv[:-k]))
    return float(t[i])


def plot_smoothing(recs: Sequence[Record], coarse: Sequence[Record], snippets: Sequence[Record], path: str,
                   cmd: str):
    """Control TV, nominal RMSE and friction peak against the smoothing width, and a current snippet."""
    fig, ax = plt.subplots(1, 4, figsize=(17, 4))
    groups = [(recs, "-")] + [([r for r in coarse if r.params["h"] == h], ls)
                              for h, ls in zip(sorted({r.params["h"] for r in coarse}), ("--", ":", "-."))]
    for group, ls in groups:
        if not group:
            continue
        tag = f"h={group[0].params['h']:g}"
        for n, c in zip(NS, ("C0", "C1", "C2")):
            rs = sorted((r for r in group if r.params["n"] == n), key=lambda r: r.params["smoothing"])
            if not rs:
                continue
            w = [max(r.params["smoothing"], 0.3) for r in rs]  # w = 0 drawn at 0.3 on the log axis
            for a, key in zip(ax[:3], ("tv_u_rate", "rmse_quiet", "max_abs_e_friction")):
                y = [r.get(key) if not r.get("diverged", False) else np.nan for r in rs]
                a.loglog(w, y, ls, color=c, marker="o", ms=3, label=f"n={n}, {tag}")
    for a, lab in zip(ax[:3], ("control TV rate [mA/s]", "quiet RMSE [rad/s]", "peak |e| in friction [rad/s]")):
        a.set_xlabel("smoothing width w (w = 0 plotted at 0.3)")
        a.set_ylabel(lab)
    ax[0].legend(fontsize=6)
    lo, hi = [], []
    t0 = _busiest_window(snippets[0].traj, 0.02) if snippets else 0.0
    for r in snippets:
        tr = r.traj
        sel = (tr.t >= t0) & (tr.t < t0 + 0.02)
        ax[3].plot(tr.t[sel], tr.u_applied[sel], lw=0.6, label=f"w = {r.params['smoothing']:g}")
        if sel.any():
            lo.append(tr.u_applied[sel].min())
            hi.append(tr.u_applied[sel].max())
    if lo:
        pad = 0.1 * (max(hi) - min(lo) + 1e-9)
        ax[3].set_ylim(min(lo) - pad, max(hi) + pad)
    ax[3].set_xlabel("time [s] (20 ms of most plain-law switching)")
    ax[3].set_ylabel("applied current [mA], every control step")
    ax[3].legend(fontsize=7)
    fig.suptitle("Plain Sontag law (w = 0) against sign(s) smoothed to s/sqrt(s^2+w^2)", fontsize=10)
    fig.text(0.01, 0.003, _made_by(cmd), fontsize=7, color="gray")
    fig.tight_layout(rect=(0, 0.03, 1, 0.95))
    fig.savefig(path, dpi=80)
    plt.close(fig)


def _lost_grid(ax, table: dict, h: float, title: str):
    """Heat map of the lost-track share over (f_r, sigma) at period h; table as rules.lost_table(h, fr, sigma)."""
    frs = sorted({k[1] for k in table if k[0] == h})
    sgs = sorted({k[2] for k in table if k[0] == h})
    grid = np.full((len(frs), len(sgs)), np.nan)
    for (hh, fr, sg), row in table.items():
        if hh == h:
            grid[frs.index(fr), sgs.index(sg)] = row[0]
    im = ax.imshow(grid, vmin=0.0, vmax=1.0, cmap="magma_r", aspect="auto", origin="lower")
    for i in range(len(frs)):
        for j in range(len(sgs)):
            if np.isfinite(grid[i, j]):
                ax.text(j, i, f"{grid[i, j]:.0%}", ha="center", va="center", fontsize=7,
                        color="w" if grid[i, j] > 0.5 else "k")
    ax.set_xticks(range(len(sgs)), [fmt_axis(v) for v in sgs], fontsize=7)
    ax.set_yticks(range(len(frs)), [f"{v:g}" for v in frs], fontsize=7)
    ax.set_xlabel("sigma")
    ax.set_ylabel("f_r [Hz]")
    ax.set_title(title, fontsize=8)
    return im


def plot_lost_track(new_table: dict, h_new: float, old_table: dict, h_old: float, w_table: dict, lim_table: dict,
                    roa: dict, path: str, cmd: str):
    """Where the loop loses track on the randomised scenarios, and the start-up probe behind it.

    Args:
        new_table, old_table: (h, f_r, sigma) -> lost-track row (rules.lost_table) for the corrected and the
            old (ZOH) loop; h_new, h_old their periods.
        w_table, lim_table: (f_r, w) and (f_r, limit) -> lost-track row.
        roa: (f_r, sigma, estimator) -> (largest recovered initial error, smallest lost one).
    """
    fig, axs = plt.subplots(2, 3, figsize=(15, 8.5), layout="constrained")
    ax = [axs[0, 0], axs[0, 1], axs[1, 0], axs[1, 1], axs[0, 2]]
    axs[1, 2].axis("off")
    im = _lost_grid(ax[0], new_table, h_new, f"corrected loop (foh), h = {h_new:g} s, plain law")
    _lost_grid(ax[1], old_table, h_old, f"old loop (zoh), h = {h_old:g} s, plain law")
    fig.colorbar(im, ax=ax[:2], shrink=0.8, label="lost-track share")
    for a, tab, lab in ((ax[2], w_table, "smoothing width w (0 at 0.3)"), (ax[3], lim_table, "current limit [mA]")):
        for fr in sorted({k[0] for k in tab}):
            ks = sorted(k for k in tab if k[0] == fr)
            a.semilogx([max(k[1], 0.3) for k in ks], [tab[k][0] for k in ks], "o-", ms=3, label=f"f_r = {fr:g} Hz")
        a.set_xlabel(lab)
        a.set_ylabel("lost-track share (foh)")
        a.set_ylim(-0.03, 1.03)
        a.legend(fontsize=7)
    for (sg, est), c in zip(sorted({(k[1], k[2]) for k in roa}), ("C0", "C1", "C2", "C3")):
        ks = sorted(k for k in roa if k[1] == sg and k[2] == est)
        ax[4].semilogy([k[0] for k in ks], [max(roa[k][0], 0.05) for k in ks], "o-", color=c,
                       label=f"{est}, sigma = {fmt_axis(sg)}: largest recovered")
        ax[4].semilogy([k[0] for k in ks], [roa[k][1] if math.isfinite(roa[k][1]) else np.nan for k in ks], "x:",
                       color=c)
    ax[4].set_xlabel("f_r [Hz]")
    ax[4].set_ylabel("initial error from rest [rad/s]")
    ax[4].set_title("start-up probe: largest recovered (o), first lost (x); 0 drawn at 0.05", fontsize=8)
    ax[4].legend(fontsize=7)
    fig.suptitle("Lost track under the 10 mA bound (velocity): randomised env scenarios and start-ups from rest",
                 fontsize=10)
    axs[1, 2].text(0.0, 0.0, _made_by(cmd), fontsize=7, color="gray", transform=axs[1, 2].transAxes)
    fig.savefig(path, dpi=80)
    plt.close(fig)


_PLOT_JOBS: list = []


def _run_plot_job(i: int) -> None:
    fn, args = _PLOT_JOBS[i]
    fn(*args)


def run_plot_jobs(jobs: list, workers: int = 2) -> None:
    """Draw figures; with workers > 1 and fork available, in forked processes that inherit the jobs."""
    global _PLOT_JOBS
    if workers > 1 and "fork" in mp.get_all_start_methods() and len(jobs) > 1:
        _PLOT_JOBS = jobs
        try:
            # the biggest figures first, so the two workers finish together
            order = sorted(range(len(jobs)), key=lambda i: jobs[i][0] is not plot_sweep_maps)
            with mp.get_context("fork").Pool(workers) as pool:
                pool.map(_run_plot_job, order, chunksize=1)
        finally:
            _PLOT_JOBS = []
    else:
        for fn, args in jobs:
            fn(*args)
