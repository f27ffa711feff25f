r"""The "state" estimator's bias under model mismatch: derived in closed form, measured along trajectories.

The estimator forms y^(i) = L_f^i h(x_meas) with the controller's model (docs/MODEL.md, "Estimators"). With the
true plant's parameters p (the model's are p_m) and the friction torque T_f the model leaves out, the true
derivatives along Eq. (1) differ from the estimates. Write f2(x; p) = (d_m x3 - B x2)/J, f3(x; p) =
(4 beta/V_m)(Q(x3, x4; p) - d_m x2 - c_sm x3). The true velocity derivatives are::

    x2'  = f2(x; p) - T_f / J
    x2'' = (d_m x3' - B x2' - T_f') / J,   x3' = f3(x; p)

and the estimates f2(x; p_m) and h2(x; p_m) = (d_m f3(x; p_m) - B_m f2(x; p_m)) / J_m, so the biases
b_i = estimate - truth are::

    b1 = f2(x; p_m) - f2(x; p) + T_f / J
    b2 = h2(x; p_m) - (d_m f3(x; p) - B (f2(x; p) - T_f / J) - T_f') / J

(J, B without subscript: the plant's; T_f' = A sigm'(x2) x2', the friction's rate where it is active). The
combined error then carries, velocity (s = e'' + l1 e' + l0 e; y', y'' estimated)::

    b_s = b2 + l1 b1

and position (s = e''' + l2 e'' + l1 e' + l0 e; y' = x2 is measured, y'', y''' estimated as b1, b2 above)::

    b_s = b2 + l2 b1.

The law drives the *estimated* s towards 0, so the true s settles near -b_s and the tracking error follows
e'' + l1 e' + l0 e = -b_s (velocity): a quasi-static offset e ~ -b_s / l0 where b_s varies slowly against the
surface's bandwidth f_r. Friction alone: b1 = T_f/J (36 rad/s^2 at 1.8 N m), so the velocity task settles at
e ~ -l1 T_f / (J l0) = -sqrt(2) T_f / (J omega_r) (0.135 rad/s at f_r = 60 Hz) while the friction is on; the
position task at e ~ -l2 T_f / (J l0) (2 T_f / (J omega_r^2): 4.6e-3 rad at 20 Hz).

:func:`bias_terms` evaluates the closed form; :func:`measured_bias` differentiates the logged true states by
central differences (a different computation from the closed form: no Lie derivative, no model) and subtracts
them from the estimator's logged derivatives.
"""

from __future__ import annotations

import math

import numpy as np

from ehss_gym.core.params import PlantParams


def _f2(x2, x3, p: PlantParams):
    return (p.d_m * x3 - p.B * x2) / p.J


def _f3(x2, x3, x4, p: PlantParams):
    sv = x4 / np.sqrt(x4 * x4 + p.delta_valve)
    dp = p.P_s - sv * x3
    q = p.c_d * x4 * dp / np.sqrt(p.rho * np.sqrt(dp * dp + p.dp_transition**2))
    return 4.0 * p.beta / p.V_m * (q - p.d_m * x2 - p.c_sm * x3)


def bias_terms(x: np.ndarray, plant: PlantParams, model: PlantParams, tf: np.ndarray, tf_rate: np.ndarray):
    """(b1, b2) of the closed form (module docstring) at states x (N, 4), friction torque tf and its rate (N,).

    b1 is the bias of the estimated velocity derivative x2', b2 of x2'' [rad/s^2, rad/s^3].
    """
    x2, x3, x4 = x[:, 1], x[:, 2], x[:, 3]
    f2p = _f2(x2, x3, plant)
    b1 = _f2(x2, x3, model) - f2p + tf / plant.J
    h2m = (model.d_m * _f3(x2, x3, x4, model) - model.B * _f2(x2, x3, model)) / model.J
    b2 = h2m - (plant.d_m * _f3(x2, x3, x4, plant) - plant.B * (f2p - tf / plant.J) - tf_rate) / plant.J
    return b1, b2


def combined_bias(b1: np.ndarray, b2: np.ndarray, task: str, lam: np.ndarray) -> np.ndarray:
    """b_s: the bias of the combined error s (velocity b2 + l1 b1, position b2 + l2 b1)."""
    return b2 + (lam[1] if task == "velocity" else lam[2]) * b1


def friction_rate(x2: np.ndarray, x2dot: np.ndarray, amp: np.ndarray, delta: float) -> np.ndarray:
    """T_f' = A d sigm(x2)/dx2 x2' of the active friction amplitude A [N m/s]."""
    q = x2 * x2 + delta
    return amp * delta / (q * np.sqrt(q)) * x2dot


def measured_bias(t: np.ndarray, x: np.ndarray, yest: np.ndarray, task: str):
    """(b1, b2) measured: the estimator's logged derivatives minus central differences of the true states.

    Args:
        t: sample times (uniform, every control period) [s].
        x: true plant states (N, 4).
        yest: the estimator's outputs (N, m): y, y', ..., y^(m-1).
        task: "velocity" (y' = x2', y'' = x2'') or "position" (y'' = x2', y''' = x2'').

    Returns:
        (b1, b2) on the interior samples 2 .. N-3 and their indices.
    """
    h = float(t[1] - t[0])
    w = x[:, 1]
    d1 = (w[2:] - w[:-2]) / (2 * h)  # x2' at 1..N-2
    d2 = (w[2:] - 2 * w[1:-1] + w[:-2]) / (h * h)  # x2'' at 1..N-2
    i = np.arange(2, len(t) - 2)
    k = 1 if task == "velocity" else 2
    b1 = yest[i, k] - d1[i - 1]
    b2 = yest[i, k + 1] - d2[i - 1]
    return b1, b2, i


def relative_agreement(derived: np.ndarray, measured: np.ndarray) -> float:
    """RMS of (derived - measured) over the RMS of measured (0 = exact agreement)."""
    den = math.sqrt(float(np.mean(measured**2)))
    return math.sqrt(float(np.mean((derived - measured) ** 2))) / den if den > 0 else math.nan
