r"""Butterworth reference models and output-derivative estimators (Eqs. 5, 19, 21, 24).

Both are unit-DC-gain state-variable filters of order m::

    z^(m) + c_{m-1} z^(m-1) + ... + c_1 z' + c_0 z = c_0 v

with Butterworth coefficients c_i at the cutoff omega_c = 2 pi f_c, from the
normalised polynomials' closed forms rather than the paper's rounded 2.61 / 3.41. The state is
(z, z', ..., z^(m-1)); the m-th derivative comes from the filter's own equation with the current input
(docs/MODEL.md, "Digital filters").

The coefficients and the digital forms are the same bits on every CPU: they start every episode, and a switching
loop carries a last-bit difference in them to per-cent differences in an episode's metrics. So they are computed
with IEEE-754 operations in a fixed order (square roots for the coefficients; :mod:`ehss_gym.core.smallmat` for the
matrix exponential and products), never by BLAS, whose kernels sum in an order that depends on the CPU
(docs/REPRODUCIBILITY.md).

A digital controller runs them at the control period h, in one of three schemes
(``Scenario.estimator``; the derivation and the error of each are in docs/MODEL.md, "Digital filters"):

- ``"foh"`` (default): the input is interpolated linearly between samples (first-order hold). At
  t_k, once v_k is known, the state is ``z_k = w_k + D v_k`` (a direct feed-through term), the top
  derivative comes from the filter's equation with the same v_k, and ``w_{k+1} = Phi w_k + E v_k``.
  Every output converges to the analog filter's at O(h^2).
- ``"zoh"``: the input is held (exact zero-order-hold discretisation, D = 0), but the top derivative
  takes the *current* sample: the state lags the analog filter by ~h/2 and the top derivative is
  biased by ~c_0 (h/2) v' (O(h)). The first implementation's scheme, kept to show the effect.
- ``"analog"``: the continuous filters integrated together with the plant by its RK4
  (:func:`ehss_gym.core.physics.integrate_lanes`); Phi, E, D are unused (identity, 0, 0).
"""

from __future__ import annotations

import functools
import math

import numpy as np

from . import smallmat
from .layout import (
    FB_D_OBS,
    FB_E_OBS,
    FB_PHI_EST,
    FB_PHI_OBS,
    FB_PHI_REF,
    FB_VEC,
    FB_VEC2,
    FBV_C_EST,
    FBV_C_REF,
    FBV_D_EST,
    FBV_D_REF,
    FBV_E_EST,
    FBV_E_REF,
    MAX_ORDER,
    N_FB,
)
from .registry import ESTIMATORS, entry

SCHEMES = ("foh", "zoh", "analog")  # how a continuous filter runs (an estimator's ``svf`` is one of them)


# The monic normalised Butterworth polynomials (cutoff 1 rad/s), coefficients of s^0 .. s^(m-1), in closed form: square
# roots only, which IEEE-754 rounds correctly, so they are the same bits on every machine (multiplying out the poles,
# as np.poly does, runs complex dot products in BLAS).
_SQRT2 = math.sqrt(2.0)
NORMALISED_BUTTERWORTH = {
    1: (1.0,),
    2: (1.0, _SQRT2),
    3: (1.0, 2.0, 2.0),
    4: (1.0, math.sqrt(4.0 + 2.0 * _SQRT2), 2.0 + _SQRT2, math.sqrt(4.0 + 2.0 * _SQRT2)),
}


def butterworth_coefficients(order: int, cutoff_hz: float) -> np.ndarray:
    """(c_0, ..., c_{m-1}) of the monic Butterworth polynomial at omega_c = 2 pi cutoff_hz: c_i = a_i omega_c^(m-i)
    with a_i the normalised polynomial's (:data:`NORMALISED_BUTTERWORTH`), the powers by repeated multiplication.

    Args:
        order: filter order m, 1 to 4 (:data:`ehss_gym.core.layout.MAX_ORDER`: every filter of the loop).
        cutoff_hz: cutoff frequency [Hz], > 0.
    """
    if order not in NORMALISED_BUTTERWORTH:
        raise ValueError(f"order must be an integer from 1 to {max(NORMALISED_BUTTERWORTH)}, got {order!r}")
    wc = 2.0 * math.pi * cutoff_hz
    powers = [1.0]
    for _ in range(order):
        powers.append(powers[-1] * wc)
    return np.array([a * powers[order - i] for i, a in enumerate(NORMALISED_BUTTERWORTH[order])])


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

    all read off one matrix exponential (:func:`hold_integrals_ab`).
    """
    A, b = companion(c)
    phi, g0, g1 = hold_integrals_ab(A, b.reshape(-1, 1), h)
    return phi, g0[:, 0].copy(), g1[:, 0].copy()


def hold_integrals_ab(A: np.ndarray, Bm: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(Phi, Gamma0, Gamma1) of x' = A x + Bm v (n states, p inputs) over one period h [s], as in
    :func:`hold_integrals`, from the exponential of the augmented system [[A h, Bm h, 0], [0, 0, I], [0, 0, 0]]."""
    n, p = Bm.shape
    M = np.zeros((n + 2 * p, n + 2 * p))
    M[:n, :n] = A * h
    M[:n, n:n + p] = Bm * h
    M[n:n + p, n + p:] = np.eye(p)
    E = smallmat.expm(M)
    return E[:n, :n].copy(), E[:n, n:n + p].copy(), E[:n, n + p:].copy()


def observer_matrices(cutoff_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Continuous (A, Bm) of the extended-state observer ("eso") with Butterworth error poles at ``cutoff_hz`` [Hz].

    States q = (velocity estimate w_hat [rad/s], disturbance acceleration d_hat [rad/s^2]); inputs v = (model
    acceleration a_m [rad/s^2], measured velocity w_m [rad/s])::

        w_hat' = a_m + d_hat + l1 (w_m - w_hat),    d_hat' = l2 (w_m - w_hat)

    The estimation error obeys eps'' + l1 eps' + l2 eps = (disturbance rate), so (l1, l2) = (sqrt(2) w_o, w_o^2),
    w_o = 2 pi cutoff_hz, are the second-order Butterworth coefficients.
    """
    l2, l1 = butterworth_coefficients(2, cutoff_hz)
    A = np.array([[-l1, 1.0], [-l2, 0.0]])
    Bm = np.array([[1.0, l1], [0.0, l2]])
    return A, Bm


def foh_form(phi: np.ndarray, g0: np.ndarray, g1: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(Phi, E, D) of the first-order-hold digital form (w_{k+1} = Phi w_k + E v_k, state z_k = w_k + D v_k).

    From the FOH step with z_k the state at t_k::

        z_{k+1} = Phi z_k + Gamma0 v_k + Gamma1 (v_{k+1} - v_k);  with z_k = w_k + Gamma1 v_k:
        w_{k+1} = Phi z_k + (Gamma0 - Gamma1) v_k = Phi w_k + (Phi Gamma1 + Gamma0 - Gamma1) v_k.
    """
    pg1 = np.array(smallmat.matmul(phi.tolist(), g1.reshape(len(phi), -1).tolist())).reshape(g1.shape)
    return phi, pg1 + g0 - g1, g1


@functools.lru_cache(maxsize=64)
def observer_filter(cutoff_hz: float, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(Phi, E, D) of the extended-state observer in the first-order-hold digital form at period h [s].

    Cached (read-only arrays).
    """
    A, Bm = observer_matrices(cutoff_hz)
    out = foh_form(*hold_integrals_ab(A, Bm, h))
    for arr in out:
        arr.flags.writeable = False
    return out


def digital_filter(c: np.ndarray, h: float, scheme: str = "foh") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(Phi, E, D) of the digital filter in the form the kernels run (see the module docstring).

    Args:
        c: filter coefficients (c_0, ..., c_{m-1}).
        h: control period [s].
        scheme: "foh", "zoh" or "analog" (identity and zeros: the kernels integrate that one).

    The FOH form is :func:`foh_form`'s.
    """
    if scheme not in SCHEMES:
        raise ValueError(f"scheme must be one of {list(SCHEMES)}, got {scheme!r}")
    m = len(c)
    if scheme == "analog":
        return np.eye(m), np.zeros(m), np.zeros(m)
    phi, g0, g1 = hold_integrals(c, h)
    if scheme == "zoh":
        return phi, g0, np.zeros(m)
    return foh_form(phi, g0, g1)


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


def filter_block(order: int, ref_hz: float, est_hz: float, h: float, estimator: str = "foh",
                 observer_hz: float = 200.0) -> np.ndarray:
    """The (N_FB, 4, 4) filter block (layout FB_*) read by the controller kernels.

    The reference model and the SVF run in the estimator's scheme (its ``svf``: "foh" for "state" and "eso", whose
    SVF rows are then unused); an estimator with an observer gets its block (bandwidth ``observer_hz`` [Hz]).

    Args:
        order: relative degree m of the output (the reference model's order; the SVF's is m - 1).
        ref_hz: reference-model cutoff [Hz].
        est_hz: SVF cutoff [Hz].
        h: control period [s].
        estimator: the estimator's name (a row of :data:`ehss_gym.core.registry.ESTIMATORS`).
        observer_hz: the observer's error bandwidth [Hz].
    """
    row = entry(ESTIMATORS, estimator, "estimator")
    cr, pr, er, dr = padded_filter(order, ref_hz, h, row.svf)
    ce, pe, ee, de = padded_filter(order - 1, est_hz, h, row.svf)
    f = np.zeros((N_FB, MAX_ORDER, MAX_ORDER))
    if row.observer:
        po, eo, do = observer_filter(float(observer_hz), float(h))
        f[FB_PHI_OBS, :2, :2] = po
        f[FB_E_OBS, :2, :2] = eo
        f[FB_D_OBS, :2, :2] = do
    f[FB_PHI_REF] = pr
    f[FB_PHI_EST] = pe
    f[FB_VEC, FBV_C_REF] = cr
    f[FB_VEC, FBV_C_EST] = ce
    f[FB_VEC, FBV_E_REF] = er
    f[FB_VEC, FBV_E_EST] = ee
    f[FB_VEC2, FBV_D_REF] = dr
    f[FB_VEC2, FBV_D_EST] = de
    return f
