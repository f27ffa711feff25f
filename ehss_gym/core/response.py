"""Control-toolbox views of a run: step-response metrics and the closed-loop frequency response.

- :func:`step_metrics`: rise time (10-90 %), settling time (2 % band), overshoot and steady-state error of a
  response to a step, computed from the sampled output with linear interpolation between samples (the usual
  definitions, as in MATLAB's ``stepinfo``); :func:`~ehss_gym.core.metrics.summarize` adds them when the
  reference is a step.
- :func:`frequency_response`: the closed loop's response from the raw reference r to the output y, estimated
  from a run with a broadband reference (chirp or multi-sine) by Welch-averaged cross spectra (the H1
  estimator, H = S_ry / S_rr) with its coherence, so the estimate is only trusted where the run excited it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .filters import butterworth_coefficients

SETTLING_BAND = 0.02  # settling: |y - y_final| within this share of the step
RISE_LOW, RISE_HIGH = 0.1, 0.9  # rise time between these shares of the step
FINAL_SHARE = 0.1  # the final value is the mean of y over this last share of the window after the step


def _crossing(t: np.ndarray, x: np.ndarray, level: float) -> float:
    """First time ``x`` reaches ``level`` (linear interpolation between samples) [s]; NaN if never."""
    idx = np.flatnonzero(x >= level)
    if not idx.size:
        return math.nan
    i = int(idx[0])
    if i == 0:
        return float(t[0])
    return float(t[i - 1] + (level - x[i - 1]) / (x[i] - x[i - 1]) * (t[i] - t[i - 1]))


def step_metrics(t, y, t_step: float, y_start: float, y_target: float) -> dict:
    """Rise time, settling time, overshoot and steady-state error of a step response.

    The response is normalised as x = (y - y_start) / (y_target - y_start) over t >= t_step, so it rises from 0
    towards 1 whichever sign the step has.

    Args:
        t: sample times [s], increasing.
        y: the output at those times [output unit].
        t_step: when the step happens [s].
        y_start: the output's level before the step (the step's start) [output unit].
        y_target: the level the step asks for [output unit].

    Returns:
        ``rise_time`` [s] (from 10 % to 90 % of the step), ``settling_time`` [s] (from the step until x stays
        within 1 +- 2 %; inf if it never does within the window), ``overshoot`` [%] (100 max(x - 1, 0)),
        ``peak_time`` [s] (from the step), ``steady_state_error`` [output unit] (y_target - the mean of y over
        the last 10 % of the window) and ``final_value`` [output unit]. NaN where undefined (no sample after the
        step, or a zero step).
    """
    t = np.asarray(t, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    nan = {"rise_time": math.nan, "settling_time": math.nan, "overshoot": math.nan, "peak_time": math.nan,
           "steady_state_error": math.nan, "final_value": math.nan}
    sel = t >= t_step
    span = y_target - y_start
    if sel.sum() < 3 or span == 0.0:
        return nan
    ts, ys = t[sel], y[sel]
    x = (ys - y_start) / span
    tail = ts >= ts[0] + (1.0 - FINAL_SHARE) * (ts[-1] - ts[0])
    final = float(ys[tail].mean())
    outside = np.flatnonzero(np.abs(x - 1.0) > SETTLING_BAND)
    if not outside.size:
        settle = 0.0
    elif outside[-1] == len(x) - 1:
        settle = math.inf
    else:  # the band is entered for good between samples outside[-1] and outside[-1] + 1
        i = int(outside[-1])
        edge = 1.0 + SETTLING_BAND * np.sign(x[i] - 1.0)
        settle = float(ts[i] + (edge - x[i]) / (x[i + 1] - x[i]) * (ts[i + 1] - ts[i]) - t_step)
    k = int(np.argmax(x))
    return {"rise_time": _crossing(ts, x, RISE_HIGH) - _crossing(ts, x, RISE_LOW), "settling_time": settle,
            "overshoot": 100.0 * max(float(x[k]) - 1.0, 0.0), "peak_time": float(ts[k] - t_step),
            "steady_state_error": float(y_target - final), "final_value": final}


@dataclass
class FrequencyResponse:
    """A closed-loop frequency response estimate r -> y.

    Attributes:
        freq: frequencies [Hz].
        gain: complex response H = Y / R [-] (output unit per output unit).
        coherence: magnitude-squared coherence of r and y [-] (1 = y is a linear response to r).
    """

    freq: np.ndarray
    gain: np.ndarray
    coherence: np.ndarray

    @property
    def magnitude_db(self) -> np.ndarray:
        """20 log10 |H| [dB]."""
        return 20.0 * np.log10(np.abs(self.gain))

    @property
    def phase_deg(self) -> np.ndarray:
        """The phase of H, unwrapped along frequency [deg]."""
        return np.degrees(np.unwrap(np.angle(self.gain)))


def _welch_spectra(dt: float, r: np.ndarray, y: np.ndarray, nperseg: int):
    """Welch-averaged (freq [Hz], S_rr, S_yy, S_ry) with Hann windows and 50 % overlap, the means removed."""
    win = np.hanning(nperseg)
    step = nperseg // 2
    starts = range(0, len(r) - nperseg + 1, step)
    srr = syy = sry = 0.0
    for s in starts:
        R = np.fft.rfft((r[s:s + nperseg] - r[s:s + nperseg].mean()) * win)
        Y = np.fft.rfft((y[s:s + nperseg] - y[s:s + nperseg].mean()) * win)
        srr = srr + (R * R.conj()).real
        syy = syy + (Y * Y.conj()).real
        sry = sry + R.conj() * Y
    return np.fft.rfftfreq(nperseg, dt), srr, syy, sry


def frequency_response(t, r, y, t_start: float = 0.2, segments: int = 16) -> FrequencyResponse:
    """The response from r to y estimated from a run with a broadband reference (a chirp or a multi-sine).

    H1 estimator: H(f) = S_ry(f) / S_rr(f) with Welch-averaged spectra (Hann windows, 50 % overlap, about
    ``2 segments - 1`` averages), and the coherence |S_ry|^2 / (S_rr S_yy). Only frequencies the reference
    excited carry information: keep those with a coherence near 1 (e.g. > 0.99) inside the chirp's sweep.

    Args:
        t: uniformly spaced sample times [s] (a Trajectory's ``t``).
        r: the reference [output unit] (``traj.r``).
        y: the output [output unit] (``traj.y``).
        t_start: samples before this time (the start-up) are left out [s].
        segments: the record is cut into about this many non-overlapping lengths (more: smoother, coarser; with
            a linear chirp, 16 keeps the estimate within ~2 % and ~1 deg of a multi-sine's, tests/test_response.py).

    Raises:
        ValueError: fewer than 64 samples after ``t_start``, or a non-uniform time grid.
    """
    t = np.asarray(t, dtype=np.float64)
    sel = t >= t_start
    t, r, y = t[sel], np.asarray(r, dtype=np.float64)[sel], np.asarray(y, dtype=np.float64)[sel]
    if len(t) < 64:
        raise ValueError(f"frequency_response needs at least 64 samples after t_start = {t_start:g} s, got {len(t)}")
    dt = float(np.median(np.diff(t)))
    if np.max(np.abs(np.diff(t) - dt)) > 1e-6 * dt:
        raise ValueError("frequency_response needs uniformly spaced samples (the run diverged or was cut?)")
    nperseg = max(32, len(t) // max(1, int(segments)))
    f, srr, syy, sry = _welch_spectra(dt, r, y, nperseg)
    keep = (f > 0) & (srr > 0) & (syy > 0)
    return FrequencyResponse(f[keep], sry[keep] / srr[keep], np.abs(sry[keep]) ** 2 / (srr[keep] * syy[keep]))


def reference_model_response(order: int, cutoff_hz: float, freq) -> np.ndarray:
    """The reference model's response c_0 / (s^m + c_{m-1} s^(m-1) + ... + c_0) at s = j 2 pi freq [-]: what the
    closed loop r -> y approaches where it tracks (y = y_d)."""
    c = butterworth_coefficients(order, cutoff_hz)
    s = 2j * np.pi * np.asarray(freq, dtype=np.float64)
    den = s**order + sum(c[i] * s**i for i in range(order))
    return c[0] / den


__all__ = ["step_metrics", "frequency_response", "FrequencyResponse", "reference_model_response", "SETTLING_BAND"]
