r"""Butterworth reference models and output-derivative estimators (Eqs. 5, 19, 21, 24).

Both are unit-DC-gain state-variable filters of order m::

    z^(m) + c_{m-1} z^(m-1) + ... + c_1 z' + c_0 z = c_0 v

with Butterworth coefficients c_i at the cutoff omega_c = 2 pi f_c, computed
from the poles rather than the paper's rounded 2.61 / 3.41 (the same operations
as ``scipy.signal.butter(..., analog=True)``, bit for bit; not importing
scipy.signal saves ~0.8 s at import). The state is (z, z', ..., z^(m-1)); the m-th derivative comes from
the filter's own equation with the current input (NOTES item 12).

A digital controller runs them at the control period h, in one of three schemes
(``Scenario.estimator``; the derivation and the error of each are in docs/MODEL.md, "Digital filters"):

- ``"foh"`` (default): the input is interpolated linearly between samples (first-order hold). At
  t_k, once v_k is known, the state is ``z_k = w_k + D v_k`` (a direct feed-through term), the top
  derivative comes from the filter's equation with the same v_k, and ``w_{k+1} = Phi w_k + E v_k``.
  Every output converges to the analog filter's at O(h^2).
- ``"zoh"``: the input is held (exact zero-order-hold discretisation, D = 0), but the top derivative
  takes the *current* sample: the state lags the analog filter by ~h/2 and the top derivative is
  biased by ~c_0 (h/2) v' (O(h)). Wave 1's scheme, kept to show the effect.
- ``"analog"``: the continuous filters integrated together with the plant by its RK4
  (:func:`ehss_gym.core.control.integrate_lanes`); Phi, E, D are unused (identity, 0, 0).
"""

from __future__ import annotations

import functools
import math

import numpy as np
import scipy.linalg

from .layout import ESTIMATORS, MAX_ORDER


def butterworth_coefficients(order: int, cutoff_hz: float) -> np.ndarray:
    """(c_0, ..., c_{m-1}) of the monic Butterworth polynomial at 2 pi cutoff_hz.

    Args:
        order: filter order m >= 1.
        cutoff_hz: cutoff frequency [Hz], > 0.
    """
    wc = 2.0 * math.pi * cutoff_hz
    poles = wc * -np.exp(1j * np.pi * np.arange(-order + 1, order, 2) / (2 * order))
    a = np.poly(poles).real
    return a[::-1][:order].copy()  # ascending powers, monic term dropped


def companion(c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Continuous (A, b) of the unit-DC-gain filter with coefficients c."""
    m = len(c)
    A = np.zeros((m, m))
    A[:-1, 1:] = np.eye(m - 1)
    A[-1, :] = -c
    b = np.zeros(m)
    b[-1] = c[0]
    return A, b


def discretise(c: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact ZOH discretisation (Phi, Gamma) at period h [s]: x_{k+1} = Phi x_k + Gamma v_k for v held."""
    phi, g0, _ = hold_integrals(c, h)
    return phi, g0


def hold_integrals(c: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(Phi, Gamma0, Gamma1) of the unit-DC-gain filter with coefficients c over one period h [s].

    For an input that is linear over the period, v(t_k + tau) = v_k + (v_{k+1} - v_k) tau / h::

        x_{k+1} = Phi x_k + Gamma0 v_k + Gamma1 (v_{k+1} - v_k),
        Phi = e^{A h},  Gamma0 = int_0^h e^{A s} b ds,  Gamma1 = (1/h) int_0^h e^{A s} b (h - s) ds,

    all read off one matrix exponential of the augmented system [[A h, b h, 0], [0, 0, 1], [0, 0, 0]].
    """
    A, b = companion(c)
    m = len(c)
    M = np.zeros((m + 2, m + 2))
    M[:m, :m] = A * h
    M[:m, m] = b * h
    M[m, m + 1] = 1.0
    E = scipy.linalg.expm(M)
    return E[:m, :m].copy(), E[:m, m].copy(), E[:m, m + 1].copy()


def digital_filter(c: np.ndarray, h: float, scheme: str = "foh") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(Phi, E, D) of the digital filter in the form the kernels run (see the module docstring).

    Args:
        c: filter coefficients (c_0, ..., c_{m-1}).
        h: control period [s].
        scheme: "foh", "zoh" or "analog" (identity and zeros: the kernels integrate that one).

    The FOH form follows from the FOH step with z_k the state at t_k::

        z_{k+1} = Phi z_k + Gamma0 v_k + Gamma1 (v_{k+1} - v_k);  with z_k = w_k + Gamma1 v_k:
        w_{k+1} = Phi z_k + (Gamma0 - Gamma1) v_k = Phi w_k + (Phi Gamma1 + Gamma0 - Gamma1) v_k.
    """
    if scheme not in ESTIMATORS:
        raise ValueError(f"estimator must be one of {list(ESTIMATORS)}, got {scheme!r}")
    m = len(c)
    if scheme == "analog":
        return np.eye(m), np.zeros(m), np.zeros(m)
    phi, g0, g1 = hold_integrals(c, h)
    if scheme == "zoh":
        return phi, g0, np.zeros(m)
    return phi, phi @ g1 + g0 - g1, g1


@functools.lru_cache(maxsize=256)
def padded_filter(order: int, cutoff_hz: float, h: float, scheme: str = "foh", size: int = MAX_ORDER):
    """Coefficients c, Phi, E and D zero-padded to ``size`` for the batched kernels.

    Cached (read-only arrays): every scenario of a sweep or an env reset reuses them.
    """
    c = butterworth_coefficients(order, cutoff_hz)
    phi, e, d = digital_filter(c, h, scheme)
    cp = np.zeros(size)
    cp[:order] = c
    P = np.zeros((size, size))
    P[:order, :order] = phi
    ep = np.zeros(size)
    ep[:order] = e
    dp = np.zeros(size)
    dp[:order] = d
    for arr in (cp, P, ep, dp):
        arr.flags.writeable = False
    return cp, P, ep, dp
