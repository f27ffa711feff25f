r"""How faithful the digital filters are to the analog ones: the measurements behind ``ehss fidelity``.

The paper's reference model and output-derivative estimator are continuous-time filters; the controller
runs them digitally at its period h (``Scenario.estimator``, derivation in docs/MODEL.md, "Digital
filters"). This module measures, for the schemes "zoh" and "foh" at h = 30, 10 and 3 us:

(a) open loop: each filter driven by the sampled paper sine v = sin(2 t) (amplitude 1 in the output unit)
    through the kernels' own functions (:func:`ehss_gym.core.estimators.filter_outputs`,
    :func:`ehss_gym.core.estimators.advance_filter` on :func:`ehss_gym.core.filters.padded_filter`), against the
    continuous filter's exact steady-state response, Im((j w)^i c_0 / P(j w) e^{j w t}), at the samples:
    the RMS and relative RMS error of every derivative, and the error of the top derivative fitted by least
    squares to the signals it can come from, ``err = beta v' + alpha v''`` (beta predicted c_0 h / 2 for
    ZOH, alpha predicted -c_0 h^2 / 12 for FOH);
(b) closed loop: the paper's velocity run and the position run at the paper's gains, with the "zoh",
    "foh" and "analog" filters at each h: the RMSE of e on [1 s, t_end), its ratio to the analog loop's,
    the RMS distance of e from the analog loop's e, the share of saturated steps and the median
    |psi/G| and |u_base| [mA].

:func:`run_all` makes every measurement; :mod:`ehss_gym.reporting.fidelity` writes ``FIDELITY.md``, the
CSVs, the figure and the table block of docs/MODEL.md. Units: time [s], h [s] (tables in us), velocity
[rad/s], position [rad], current [mA].
"""

from __future__ import annotations

import math
import sys
import time

import numpy as np
from tqdm import tqdm

from ehss_gym.core.estimators import advance_filter, filter_outputs
from ehss_gym.core.filters import butterworth_coefficients, padded_filter
from ehss_gym.core.jit import jit
from ehss_gym.core.layout import L_E, L_UBASE, L_X, L_YD
from ehss_gym.core.physics import lie_derivatives
from ehss_gym.core.sim import Scenario, lambdas, simulate_batch
from ehss_gym.envs import DEFAULTS

PROG = "ehss fidelity"
PERIODS = (3e-5, 1e-5, 3e-6)  # control periods h [s] of the order fits
QUICK_PERIODS = (3e-5, 1e-5)  # closed-loop periods with --quick [s]
SCHEMES = ("zoh", "foh")  # the digital schemes; "analog" is the reference
CLOSED_SCHEMES = ("zoh", "foh", "analog")
TASK_ORDER = {"velocity": 3, "position": 4}  # relative degree m
OMEGA = 2.0  # the paper's reference sine, amplitude 1 [output unit], angular frequency [rad/s]
ESTIMATOR_HZ = 1000.0  # estimator cutoff [Hz] (Table I)
REF_MODEL_HZ = 20.0  # reference-model cutoff [Hz] (Table I)
SETTLE = 0.5  # open loop: start-up time left out [s] (the slowest pole, 20 Hz order 4, decays at 48 /s)
WINDOW = math.pi  # open loop: analysed time [s], one period of sin(2 t)
T_FROM = 1.0  # closed loop: the RMSE window starts here [s]
T_END = 8.0  # closed loop: run length [s]
QUICK_T_END = 2.0  # closed loop with --quick [s]


# ------------------------------------------------------------------------------------------------
# Open loop
# ------------------------------------------------------------------------------------------------


@jit
def _drive_filter(c, phi, e, d, order, h, omega, k0, n, z0, out):
    """Run one digital filter on v_k = sin(omega k h) with the kernels' functions; outputs from step k0 on.

    Args:
        c, phi, e, d: the padded filter (:func:`ehss_gym.core.filters.padded_filter`).
        order: filter order.
        h: period [s].
        omega: input angular frequency [rad/s].
        k0: first step written to ``out``.
        n: number of steps.
        z0: the state z at t = 0 (v(0) = 0, so w_0 = z_0 - D v_0 = z_0).
        out: (n - k0, order + 1) receives z_0..z_{order-1} and the top derivative at each sample.
    """
    z = np.zeros(4)
    o = np.zeros(4)
    tmp = np.zeros(4)
    for i in range(order):
        z[i] = z0[i]
    for k in range(n):
        v = math.sin(omega * (k * h))
        top = filter_outputs(z, 0, order, c, d, v, o, 0)
        if k >= k0:
            for i in range(order):
                out[k - k0, i] = o[i]
            out[k - k0, order] = top
        advance_filter(z, 0, order, phi, e, v, tmp)


def _response_coefficients(order: int, cutoff_hz: float, omega: float, i: int) -> complex:
    """(j w)^i H(j w): the i-th derivative of the steady-state response to sin(w t) is Im(that * e^{j w t}).

    Args:
        order: filter order m.
        cutoff_hz: Butterworth cutoff [Hz].
        omega: input angular frequency [rad/s].
        i: derivative (0..m).
    """
    c = butterworth_coefficients(order, cutoff_hz)
    s = 1j * omega
    P = s**order + sum(c[j] * s**j for j in range(order))
    return complex(s**i * c[0] / P)


def analog_sine_response(order: int, cutoff_hz: float, omega: float, t: np.ndarray, i: int) -> np.ndarray:
    """i-th derivative of the continuous filter's steady-state response to sin(omega t): Im((j w)^i H(j w) e^{j w t}).

    Args:
        order: filter order m.
        cutoff_hz: Butterworth cutoff [Hz].
        omega: input angular frequency [rad/s].
        t: times [s].
        i: derivative (0..m).

    Returns:
        The response [input unit / s^i] at ``t``.
    """
    X = _response_coefficients(order, cutoff_hz, omega, i)
    return X.imag * np.cos(omega * t) + X.real * np.sin(omega * t)


def _fit(err: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """Least-squares (p, q) of err = p a + q b (normal equations: a and b are two smooth signals)."""
    M = np.array([[a @ a, a @ b], [a @ b, b @ b]])
    p, q = np.linalg.solve(M, np.array([a @ err, b @ err]))
    return float(p), float(q)


def open_loop_filter(order: int, cutoff_hz: float, h: float, scheme: str) -> list[dict]:
    """One digital filter against the analog one on the paper's sine; one row per derivative 1..order.

    Args:
        order: filter order.
        cutoff_hz: cutoff [Hz].
        h: period [s].
        scheme: "zoh" or "foh".

    Returns:
        Rows with the RMS error [unit / s^i], the relative RMS error, the literal fit
        ``err = a v^(i) + b v^(i-1)`` and, for the top derivative, ``err = beta v' + alpha v''`` with
        beta / (c_0 h / 2) and alpha / (-c_0 h^2 / 12).
    """
    c, phi, e, d = padded_filter(order, cutoff_hz, h, scheme)
    c0 = float(c[0])
    k0 = int(math.ceil(SETTLE / h))
    n = k0 + int(round(WINDOW / h))
    t = np.arange(k0, n) * h
    sn, cs = np.sin(OMEGA * t), np.cos(OMEGA * t)
    # v^(i) = Im((j w)^i e^{j w t}): the input's derivatives, the signals an error can come from
    dv = [(OMEGA**i) * (sn, cs, -sn, -cs)[i % 4] for i in range(order + 1)]
    z0 = np.zeros(4)
    for i in range(order):
        z0[i] = _response_coefficients(order, cutoff_hz, OMEGA, i).imag  # the analog state at t = 0
    out = np.zeros((n - k0, order + 1))
    _drive_filter(c, phi, e, d, order, h, OMEGA, k0, n, z0, out)
    rows = []
    for i in range(1, order + 1):
        X = _response_coefficients(order, cutoff_hz, OMEGA, i)
        want = X.imag * cs + X.real * sn
        err = out[:, i] - want
        a, b = _fit(err, dv[i], dv[i - 1])
        row = dict(order=order, cutoff_hz=cutoff_hz, scheme=scheme, h=h, derivative=i, top=int(i == order), c0=c0,
                   rms_err=float(np.sqrt(np.mean(err**2))), rms_signal=float(np.sqrt(np.mean(want**2))),
                   fit_a=a, fit_b=b, beta=math.nan, beta_ratio=math.nan, alpha=math.nan, alpha_ratio=math.nan)
        row["rel_rms"] = row["rms_err"] / row["rms_signal"]
        if i == order:
            beta, alpha = _fit(err, dv[1], dv[2])
            row.update(beta=beta, beta_ratio=beta / (c0 * h / 2.0), alpha=alpha,
                       alpha_ratio=alpha / (-c0 * h * h / 12.0))
        rows.append(row)
    return rows


def open_loop_jobs(periods=PERIODS) -> list[tuple[str, str, int, float, str, float]]:
    """(task, filter, order, cutoff [Hz], scheme, h [s]) of every open-loop case."""
    jobs = []
    for task, m in TASK_ORDER.items():
        for name, order, hz in (("estimator", m - 1, ESTIMATOR_HZ), ("reference model", m, REF_MODEL_HZ)):
            for scheme in SCHEMES:
                for h in periods:
                    jobs.append((task, name, order, hz, scheme, h))
    return jobs


# ------------------------------------------------------------------------------------------------
# Closed loop
# ------------------------------------------------------------------------------------------------


def closed_loop_scenario(task: str, h: float, estimator: str, t_end: float = T_END) -> Scenario:
    """The paper's velocity run, or the position run at the paper's gains, without friction.

    Args:
        task: "velocity" (n = 2, f_r = 100 Hz, sigma = 1e5, w = 100) or "position" (n = 2, f_r = 60 Hz,
            sigma = 1e7, plain law).
        h: control period [s] (one RK4 substep).
        estimator: "zoh", "foh" or "analog".
        t_end: run length [s].
    """
    if task == "velocity":
        kw = dict(fr=100.0, sigma=1e5, smoothing=100.0)
    else:
        kw = dict(fr=60.0, sigma=1e7, smoothing=0.0)
    return Scenario(task=task, n=2, current_limit=10.0, control_period=h, substeps=1, t_end=t_end, friction=(),
                    estimator=estimator, estimator_hz=ESTIMATOR_HZ, ref_model_hz=REF_MODEL_HZ, **kw)


@jit
def _psi_over_g_and_top(log, m, lam, model_p, out, top):
    """Per logged row: |psi/G| [mA] as the controller formed it, and the plant's true y^(m-1).

    psi = F(x) - y_d^(m) + sum_j lam_j e^(j+1); y^(m-1) is the true value of the estimator's top output
    (omega'' [rad/s^3] for velocity, theta''' [rad/s^3] for position), from the state along the model.

    Args:
        log: trajectory log rows (layout L_*).
        m: relative degree.
        lam: combined-error coefficients lambda_0..lambda_{m-2}.
        model_p: the controller's plant model (PlantParams.as_array()).
        out: receives |psi/G| (NaN where G is 0 or not finite).
        top: receives y^(m-1) [rad/s^3].
    """
    hd = np.zeros(4)
    x = np.zeros(4)
    for i in range(log.shape[0]):
        for j in range(4):
            x[j] = log[i, L_X + j]
        F, G = lie_derivatives(x, model_p, m, hd)
        top[i] = hd[m - 1]
        psi = F - log[i, L_YD + m]
        for j in range(m - 1):
            psi += lam[j] * log[i, L_E + j + 1]
        if G != 0.0 and math.isfinite(G):
            out[i] = abs(psi / G)
        else:
            out[i] = math.nan


def closed_loop(periods=PERIODS, t_end: float = T_END, bar=None) -> list[dict]:
    """The closed-loop runs at each period; one row per (task, h, scheme).

    Args:
        periods: control periods [s].
        t_end: run length [s]; statistics over the logged samples with T_FROM <= t < t_end.
        bar: optional tqdm bar, advanced once per period.

    Returns:
        Rows with rmse [output unit], ratio to the analog loop's, dev_analog (RMS of e - e_analog
        [output unit]), saturation (share of all control steps of the run), median |psi/G| and |u_base| [mA],
        rms_y_top (RMS of the plant's true y^(m-1) [rad/s^3]), rms_yd_top (RMS of the reference model's
        y_d^(m-1) [rad/s^3]) and max_abs_e (max |e| [output unit]), all on the window.
    """
    rows = []
    for h in periods:
        scs = [closed_loop_scenario(task, h, est, t_end) for task in TASK_ORDER for est in CLOSED_SCHEMES]
        trs = simulate_batch(scs)
        by = {(tr.scenario.task, tr.scenario.estimator): tr for tr in trs}
        for task in TASK_ORDER:
            ref = by[(task, "analog")]
            sel_ref = (ref.t >= T_FROM) & (ref.t < t_end)
            rmse_ref = float(np.sqrt(np.mean(ref.e[sel_ref] ** 2)))
            for est in CLOSED_SCHEMES:
                tr = by[(task, est)]
                sc = tr.scenario
                sel = (tr.t >= T_FROM) & (tr.t < t_end)
                rmse = float(np.sqrt(np.mean(tr.e[sel] ** 2)))
                if len(tr.t) == len(ref.t):
                    dev = float(np.sqrt(np.mean((tr.e[sel] - ref.e[sel]) ** 2)))
                else:  # one of them diverged
                    dev = math.nan
                pg = np.empty(int(sel.sum()))
                top = np.empty(int(sel.sum()))
                _psi_over_g_and_top(np.ascontiguousarray(tr.log[sel]), sc.order, lambdas(sc.order, sc.fr),
                                    (sc.model or sc.plant).as_array(), pg, top)
                m = tr.metrics()
                rows.append(dict(task=task, h=h, scheme=est, t_end=t_end, rmse=rmse, ratio_analog=rmse / rmse_ref,
                                 dev_analog=dev, saturation=m["saturation"], median_psi_over_g=float(np.nanmedian(pg)),
                                 median_u_base=float(np.median(np.abs(tr.log[sel, L_UBASE]))),
                                 rms_y_top=float(np.sqrt(np.mean(top**2))),
                                 rms_yd_top=float(np.sqrt(np.mean(tr.log[sel, L_YD + sc.order - 1] ** 2))),
                                 max_abs_e=float(np.max(np.abs(tr.e[sel]))),
                                 tv_u_rate=m["tv_u_rate"], diverged=int(tr.diverged)))
        if bar is not None:
            bar.update(1)
    return rows


# ------------------------------------------------------------------------------------------------
# Report
# ------------------------------------------------------------------------------------------------


def observed_order(hs, errs) -> float:
    """Slope of log(error) against log(h), the observed convergence order (NaN if an error is not positive)."""
    hs = np.asarray(hs, float)
    errs = np.asarray(errs, float)
    if len(hs) < 2 or not np.all(np.isfinite(errs)) or np.any(errs <= 0):
        return math.nan
    return float(np.polyfit(np.log(hs), np.log(errs), 1)[0])


def lambda0(task: str) -> float:
    """lambda_0 of the closed-loop scenario's combined error [1/s^(m-1)]."""
    sc = closed_loop_scenario(task, PERIODS[0], "foh")
    return float(lambdas(sc.order, sc.fr)[0])


def run_all(quick: bool = False, progress: bool = True) -> dict:
    """Every open-loop and closed-loop measurement; a dict of rows and the settings they were made at.

    Args:
        quick: closed loop at 30 and 10 us only, for QUICK_T_END s (the open loop is the same; it is cheap).
        progress: show a tqdm bar on stderr.
    """
    t0 = time.perf_counter()
    # the closed loop also at the env's default period (a change of the default period must keep the fidelity it had)
    cl_periods = QUICK_PERIODS if quick else tuple(sorted(set(PERIODS) | {DEFAULTS.control_period}, reverse=True))
    t_end = QUICK_T_END if quick else T_END
    jobs = open_loop_jobs(PERIODS)
    bar = tqdm(total=len(jobs) + len(cl_periods), desc="ehss fidelity", unit="job", file=sys.stderr,
               disable=not progress)
    ol = []
    for task, name, order, hz, scheme, h in jobs:
        for r in open_loop_filter(order, hz, h, scheme):
            ol.append(dict(task=task, filter=name, **r))
        bar.update(1)
    cl = closed_loop(cl_periods, t_end, bar)
    bar.close()
    return {"ol": ol, "cl": cl, "periods": PERIODS, "cl_periods": cl_periods, "t_end": t_end, "quick": quick,
            "wall_s": time.perf_counter() - t0}
