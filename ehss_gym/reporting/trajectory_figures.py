"""Figures of closed-loop runs (matplotlib, Agg backend: no screen needed); public as :mod:`ehss_gym.plotting`."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ehss_gym.core.settings import UNITS  # noqa: E402

COHERENCE_MIN = 0.99  # frequencies with less coherence are drawn faint: the run did not excite them enough


def _title(traj) -> str:
    return _scenario_title(traj.scenario)


def _scenario_title(sc) -> str:
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


def frequency_response_figure(fr, scenario=None, made_by: str | None = None, reference=None):
    """A Bode plot (magnitude [dB] and phase [deg] against frequency [Hz], log axis) of a frequency response.

    Args:
        fr: a :class:`~ehss_gym.core.response.FrequencyResponse` (its low-coherence points drawn faint).
        scenario: the run's Scenario, for the title and the chirp's sweep band (shaded).
        made_by: the command that made the figure, printed in the footer.
        reference: optional (freq [Hz], complex H) drawn as a dashed line, e.g. the reference model's response.
    """
    fig, (am, ap) = plt.subplots(2, 1, figsize=(8, 6.5), sharex=True)
    band = excited_band(fr, scenario)
    inb = (fr.freq >= band[0]) & (fr.freq <= band[1])
    good = inb & (fr.coherence >= COHERENCE_MIN)
    f = fr.freq[good]
    am.semilogx(f, fr.magnitude_db[good], "C0o-", lw=1.2, ms=2.5, label=f"estimate (coherence >= {COHERENCE_MIN})")
    ap.semilogx(f, np.degrees(np.unwrap(np.angle(fr.gain[good]))), "C0o-", lw=1.2, ms=2.5, label="estimate")
    weak = inb & ~good
    if weak.any():
        am.semilogx(fr.freq[weak], fr.magnitude_db[weak], "C0x", ms=3, alpha=0.4, label="low coherence")
    if reference is not None:
        f, H = reference
        sel = (f >= band[0]) & (f <= band[1])
        am.semilogx(f[sel], 20 * np.log10(np.abs(H[sel])), "k--", lw=1, label="reference model (the loop's target)")
        ap.semilogx(f[sel], np.degrees(np.unwrap(np.angle(H[sel]))), "k--", lw=1)
    am.set_xlim(*band)
    am.set_ylabel("|y / r| [dB]")
    ap.set_ylabel("phase [deg]")
    ap.set_xlabel("frequency [Hz]")
    am.legend(fontsize=7, loc="lower left")
    am.grid(True, which="both", alpha=0.3)
    ap.grid(True, which="both", alpha=0.3)
    ttl = "closed-loop frequency response r -> y (Welch H1 estimate)"
    if scenario is not None:
        ttl += "\n" + _scenario_title(scenario)
    fig.suptitle(ttl, fontsize=9)
    if made_by:
        fig.text(0.01, 0.005, f"made by: {made_by}", fontsize=7, color="gray")
    fig.tight_layout(rect=(0, 0.02, 1, 1))
    return fig


def excited_band(fr, scenario=None) -> tuple[float, float]:
    """The frequencies [Hz] a run's reference excited: a chirp's sweep, a multi-sine's lowest to highest line
    (each with a 20 % margin), else all of ``fr``."""
    if scenario is not None and scenario.reference.family in ("chirp", "multisine"):
        spec = scenario.reference.spec
        if scenario.reference.family == "chirp":
            w = (spec[5], spec[7])
        else:
            w = [spec[9 + 3 * i] for i in range(4) if spec[8 + 3 * i] != 0.0]
        lo, hi = min(w) / (2 * np.pi), max(w) / (2 * np.pi)
        return max(lo / 1.2, float(fr.freq[0])), hi * 1.2
    return float(fr.freq[0]), float(fr.freq[-1])


def plot_frequency_response(fr, path, scenario=None, made_by: str | None = None, reference=None) -> str:
    """Write :func:`frequency_response_figure` as a PNG; returns ``path``."""
    fig = frequency_response_figure(fr, scenario, made_by, reference)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return str(path)
