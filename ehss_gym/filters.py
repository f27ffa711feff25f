r"""Butterworth reference models and output-derivative estimators (Eqs. 5, 19, 21, 24).

Both are unit-DC-gain state-variable filters of order m::

    z^(m) + c_{m-1} z^(m-1) + ... + c_1 z' + c_0 z = c_0 v

with Butterworth coefficients c_i at the cutoff omega_c = 2 pi f_c, computed
from the poles rather than the paper's rounded 2.61 / 3.41 (the same operations
as ``scipy.signal.butter(..., analog=True)``, bit for bit; not importing
scipy.signal saves ~0.8 s at import). The state is (z, z', ..., z^(m-1)); the m-th derivative comes from
the filter's own equation with the current input (NOTES item 12).

A digital controller runs them at the control period h. They are discretised
exactly for a zero-order-held input: z_{k+1} = Phi z_k + Gamma v_k.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import scipy.linalg

from .layout import MAX_ORDER


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
    """Exact ZOH discretisation (Phi, Gamma) at period h [s]."""
    A, b = companion(c)
    m = len(c)
    M = np.zeros((m + 1, m + 1))
    M[:m, :m] = A * h
    M[:m, m] = b * h
    E = scipy.linalg.expm(M)
    return E[:m, :m].copy(), E[:m, m].copy()


@functools.lru_cache(maxsize=256)
def padded_filter(order: int, cutoff_hz: float, h: float, size: int = MAX_ORDER):
    """Coefficients, Phi and Gamma zero-padded to ``size`` for the batched kernels.

    Cached (read-only arrays): every scenario of a sweep or an env reset reuses them.
    """
    c = butterworth_coefficients(order, cutoff_hz)
    phi, gam = discretise(c, h)
    cp = np.zeros(size)
    cp[:order] = c
    P = np.zeros((size, size))
    P[:order, :order] = phi
    g = np.zeros(size)
    g[:order] = gam
    for arr in (cp, P, g):
        arr.flags.writeable = False
    return cp, P, g
