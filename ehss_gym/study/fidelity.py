r"""How faithful the digital filters are to the analog ones: ``ehss fidelity`` (``ehss fidelity``).

The paper's reference model and output-derivative estimator are continuous-time filters; the controller
runs them digitally at its period h (``Scenario.estimator``, derivation in docs/MODEL.md, "Digital
filters"). This module measures, for the schemes "zoh" and "foh" at h = 30, 10 and 3 us:

(a) open loop: each filter driven by the sampled paper sine v = sin(2 t) (amplitude 1 in the output unit)
    through the kernels' own functions (:func:`ehss_gym.core.control.filter_outputs`,
    :func:`ehss_gym.core.control.advance_filter` on :func:`ehss_gym.core.filters.padded_filter`), against the
    continuous filter's exact steady-state response, Im((j w)^i c_0 / P(j w) e^{j w t}), at the samples:
    the RMS and relative RMS error of every derivative, and the error of the top derivative fitted by least
    squares to the signals it can come from, ``err = beta v' + alpha v''`` (beta predicted c_0 h / 2 for
    ZOH, alpha predicted -c_0 h^2 / 12 for FOH);
(b) closed loop: the paper's velocity run and the position run at the paper's gains, with the "zoh",
    "foh" and "analog" filters at each h: the RMSE of e on [1 s, t_end), its ratio to the analog loop's,
    the RMS distance of e from the analog loop's e, the share of saturated steps and the median
    |psi/G| and |u_base| [mA].

It writes ``FIDELITY.md``, ``data/*.csv`` and ``figures/order.png`` under ``--out`` and replaces the block
between ``<!-- fidelity-table:begin -->`` and ``<!-- fidelity-table:end -->`` in ``--docs``. All files are
written atomically. Units: time [s], h [s] (tables in us), velocity [rad/s], position [rad], current [mA].
"""

from __future__ import annotations

import csv
import io
import math
import os
import sys
import time

import numpy as np

from ehss_gym._version import __version__
from ehss_gym.core.control import advance_filter, filter_outputs
from ehss_gym.core.filters import butterworth_coefficients, padded_filter
from ehss_gym.core.layout import L_E, L_UBASE, L_X, L_YD
from ehss_gym.core.physics import jit, lie_derivatives
from ehss_gym.core.sim import Scenario, lambdas, simulate_batch
from ehss_gym.core.util import atomic_write, atomic_write_text
from ehss_gym.envs import DEFAULTS

PROG = "ehss fidelity"
PERIODS = (3e-5, 1e-5, 3e-6)  # control periods h [s] of the order fits
QUICK_PERIODS = (3e-5, 1e-5)  # closed-loop periods with --quick [s]
SCHEMES = ("zoh", "foh")  # the digital schemes; "analog" is the reference
CLOSED_SCHEMES = ("zoh", "foh", "analog")
TASK_ORDER = {"velocity": 3, "position": 4}  # relative degree m
UNITS = {"velocity": "rad/s", "position": "rad"}
OMEGA = 2.0  # the paper's reference sine, amplitude 1 [output unit], angular frequency [rad/s]
ESTIMATOR_HZ = 1000.0  # estimator cutoff [Hz] (Table I)
REF_MODEL_HZ = 20.0  # reference-model cutoff [Hz] (Table I)
SETTLE = 0.5  # open loop: start-up time left out [s] (the slowest pole, 20 Hz order 4, decays at 48 /s)
WINDOW = math.pi  # open loop: analysed time [s], one period of sin(2 t)
T_FROM = 1.0  # closed loop: the RMSE window starts here [s]
T_END = 8.0  # closed loop: run length [s]
QUICK_T_END = 2.0  # closed loop with --quick [s]
BEGIN = "<!-- fidelity-table:begin -->"
END = "<!-- fidelity-table:end -->"


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


def _g(x: float, digits: int = 3) -> str:
    """A number for a table: 3 significant digits, 'nan' kept visible."""
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "nan"
    return f"{x:.{digits}g}"


def _us(h: float) -> str:
    return f"{h * 1e6:g}"


def _order(hs, errs) -> float:
    """Slope of log(error) against log(h), the observed convergence order (NaN if an error is not positive)."""
    hs = np.asarray(hs, float)
    errs = np.asarray(errs, float)
    if len(hs) < 2 or not np.all(np.isfinite(errs)) or np.any(errs <= 0):
        return math.nan
    return float(np.polyfit(np.log(hs), np.log(errs), 1)[0])


def _csv(rows: list[dict], cols: list[str]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(cols)
    for r in rows:
        w.writerow([f"{r[c]:.10g}" if isinstance(r[c], float) else r[c] for c in cols])
    return buf.getvalue()


OPEN_COLS = ["task", "filter", "order", "cutoff_hz", "scheme", "h", "derivative", "top", "c0", "rms_err", "rms_signal",
             "rel_rms", "fit_a", "fit_b", "beta", "beta_ratio", "alpha", "alpha_ratio"]
CLOSED_COLS = ["task", "h", "scheme", "t_end", "rmse", "ratio_analog", "dev_analog", "saturation", "median_psi_over_g",
               "median_u_base", "rms_y_top", "rms_yd_top", "max_abs_e", "tv_u_rate", "diverged"]

MAIN_LEGEND = (
    "Columns: *open-loop top-derivative error* is the relative RMS error of the estimator's top derivative "
    "(y_e'' velocity, y_e''' position) driven open loop by the sampled sin(2t), against the analog filter's "
    "exact steady-state response; *bias / (c0 h/2)* is the coefficient of y' in the least-squares fit "
    "err = beta y' + alpha y'' of that error, divided by the ZOH prediction c0 h/2 (c0 = (2 pi 1000 Hz)^(m-1)); "
    "*RMSE* is the closed-loop RMS of e on [1 s, t_end) (velocity [rad/s]: the paper's run, n = 2, f_r = 100 Hz, "
    "sigma = 1e5, w = 100; position [rad]: f_r = 60 Hz, sigma = 1e7, plain law; both 10 mA, 1 RK4 substep, "
    "no friction); */ analog* is that RMSE over the analog-filter loop's at the same h; *RMS(e - e_analog)* "
    "is the RMS distance of e from the analog loop's e on the same window; *saturated* is the share of all "
    "control steps at the current limit; *median abs(psi/G)* is the median size of the equivalent control "
    "-psi/G [mA] on the window, psi formed from the logged states as the controller formed it."
)


def main_table(ol: list[dict], cl: list[dict]) -> str:
    """The main table (markdown): per task, h and scheme, the open-loop top-derivative error and the closed loop."""
    top = {(r["task"], r["scheme"], r["h"]): r for r in ol if r["filter"] == "estimator" and r["top"]}
    lines = ["| task | h [us] | scheme | open-loop top-derivative error (rel. RMS) | bias / (c0 h/2) | RMSE | "
             "/ analog | RMS(e - e_analog) | saturated [%] | median abs(psi/G) [mA] |",
             "| --- | ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for r in cl:
        o = top.get((r["task"], r["scheme"], r["h"]))
        if r["scheme"] == "analog":
            ole = olb = "(reference)"
            ratio = dev = "(reference)"
        else:
            ole = _g(o["rel_rms"]) if o else "-"
            olb = _g(o["beta_ratio"]) if o else "-"
            ratio = _g(r["ratio_analog"])
            dev = _g(r["dev_analog"])
        lines.append(f"| {r['task']} | {_us(r['h'])} | {r['scheme']} | {ole} | {olb} | {_g(r['rmse'])} | {ratio} | "
                     f"{dev} | {_g(100 * r['saturation'])} | {_g(r['median_psi_over_g'])} |")
    return "\n".join(lines)


def _derivative_name(task: str, filt: str, i: int) -> str:
    base = "y_d" if filt == "reference model" else "y_e"
    return base + ("'" * i if i <= 4 else f"^({i})")


def open_loop_table(ol: list[dict], periods) -> str:
    """Relative RMS error of every derivative at each h, and the observed order."""
    head = " | ".join(f"rel. RMS at {_us(h)} us" for h in periods)
    lines = [f"| task | filter | derivative | scheme | {head} | observed order |",
             "| --- | --- | --- | --- | " + " | ".join("---:" for _ in periods) + " | ---: |"]
    keys = []
    for r in ol:
        k = (r["task"], r["filter"], r["derivative"], r["scheme"])
        if k not in keys:
            keys.append(k)
    for k in keys:
        rs = {r["h"]: r for r in ol if (r["task"], r["filter"], r["derivative"], r["scheme"]) == k}
        vals = [rs[h]["rel_rms"] for h in periods]
        name = _derivative_name(k[0], k[1], k[2]) + (" (top)" if rs[periods[0]]["top"] else "")
        lines.append(f"| {k[0]} | {k[1]} | {name} | {k[3]} | " + " | ".join(_g(v) for v in vals)
                     + f" | {_order(periods, vals):.2f} |")
    return "\n".join(lines)


def top_fit_table(ol: list[dict]) -> str:
    """The top derivative's error fitted to v' and v''."""
    lines = ["| task | filter | scheme | h [us] | c0 | RMS error | beta (coef. of y') | beta / (c0 h/2) | "
             "alpha (coef. of y'') | alpha / (-c0 h^2/12) |",
             "| --- | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for r in ol:
        if not r["top"]:
            continue
        lines.append(f"| {r['task']} | {r['filter']} | {r['scheme']} | {_us(r['h'])} | {_g(r['c0'])} | "
                     f"{_g(r['rms_err'])} | {_g(r['beta'])} | {_g(r['beta_ratio'], 4)} | {_g(r['alpha'])} | "
                     f"{_g(r['alpha_ratio'], 4)} |")
    return "\n".join(lines)


def _lambda0(task: str) -> float:
    """lambda_0 of the closed-loop scenario's combined error [1/s^(m-1)]."""
    sc = closed_loop_scenario(task, PERIODS[0], "foh")
    return float(lambdas(sc.order, sc.fr)[0])


def closed_extra_table(ol: list[dict], cl: list[dict]) -> str:
    """Closed-loop distance from the analog loop against its quasi-static estimate, and more columns."""
    top = {(r["task"], r["scheme"], r["h"]): r for r in ol if r["filter"] == "estimator" and r["top"]}
    lines = ["| task | h [us] | scheme | RMS(e - e_analog) | quasi-static estimate | measured / estimate | "
             "max abs(e) | median abs(u_base) [mA] | RMS of true y^(m-1) [rad/s^3] | RMS of y_d^(m-1) [rad/s^3] |",
             "| --- | ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for r in cl:
        o = top.get((r["task"], r["scheme"], r["h"]))
        if r["scheme"] == "analog" or o is None:
            dev = est = ratio = "(reference)"
        else:
            e = o["rms_err"] / _lambda0(r["task"])
            dev, est, ratio = _g(r["dev_analog"]), _g(e), _g(r["dev_analog"] / e)
        lines.append(f"| {r['task']} | {_us(r['h'])} | {r['scheme']} | {dev} | {est} | {ratio} | "
                     f"{_g(r['max_abs_e'])} | {_g(r['median_u_base'])} | {_g(r['rms_y_top'])} | "
                     f"{_g(r['rms_yd_top'])} |")
    return "\n".join(lines)


def closed_order_table(cl: list[dict], periods) -> str:
    """Observed order of RMS(e - e_analog) against h."""
    lines = ["| task | scheme | observed order of RMS(e - e_analog) |", "| --- | --- | ---: |"]
    for task in TASK_ORDER:
        for est in SCHEMES:
            rs = {r["h"]: r for r in cl if r["task"] == task and r["scheme"] == est}
            lines.append(f"| {task} | {est} | {_order(periods, [rs[h]['dev_analog'] for h in periods]):.2f} |")
    return "\n".join(lines)


def plot_order(ol: list[dict], cl: list[dict], path: str, cmd: str) -> None:
    """Log-log error against h with reference slopes 1 and 2: open loop (top derivatives) and closed loop."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter, ScalarFormatter
    fig, ax = plt.subplots(1, 2, figsize=(12, 6.8))
    colors = {"velocity": "tab:blue", "position": "tab:red"}
    marks = {"zoh": "s", "foh": "o"}
    allh = sorted({r["h"] for r in ol})
    for task in TASK_ORDER:
        for filt, ls in (("estimator", "-"), ("reference model", "--")):
            for est in SCHEMES:
                rs = sorted((r for r in ol if r["task"] == task and r["filter"] == filt and r["top"]
                             and r["scheme"] == est), key=lambda r: r["h"])
                ax[0].loglog([r["h"] * 1e6 for r in rs], [r["rel_rms"] for r in rs], ls, color=colors[task],
                             marker=marks[est], mfc="none" if filt != "estimator" else colors[task],
                             label=f"{task} {filt} top derivative, {est}")
    clh = sorted({r["h"] for r in cl})
    for task in TASK_ORDER:
        for est in SCHEMES:
            rs = sorted((r for r in cl if r["task"] == task and r["scheme"] == est), key=lambda r: r["h"])
            ax[1].loglog([r["h"] * 1e6 for r in rs], [r["dev_analog"] for r in rs], "-", color=colors[task],
                         marker=marks[est], label=f"{task} ({UNITS[task]}), {est}")
    for a, hs in ((ax[0], allh), (ax[1], clh)):
        ys = [ln.get_ydata() for ln in a.get_lines()]
        yv = np.concatenate([np.asarray(y, float) for y in ys]) if ys else np.array([1.0])
        yv = yv[np.isfinite(yv) & (yv > 0)]
        if yv.size == 0:
            yv = np.array([1.0])
        hh = np.array([min(hs), max(hs)]) * 1e6
        y0 = float(np.exp(np.mean(np.log(yv))))  # anchor the guides in the middle of the data
        hm = math.sqrt(hh[0] * hh[1])
        for p, ls in ((1, ":"), (2, "-.")):
            a.loglog(hh, y0 * (hh / hm) ** p, ls, color="gray", lw=1.2, label=f"slope {p}")
        a.set_xlabel("control period h [us]")
        a.set_xticks(hh if len(hs) < 3 else sorted(h * 1e6 for h in hs))
        a.xaxis.set_major_formatter(ScalarFormatter())
        a.xaxis.set_minor_formatter(NullFormatter())
        a.grid(True, which="both", alpha=0.3)
        a.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2)
    ax[0].set_ylabel("relative RMS error against the analog filter")
    ax[0].set_title("open loop: top derivative, input sin(2t)", fontsize=9)
    ax[1].set_ylabel("RMS(e - e_analog) on [1 s, t_end) [rad/s; rad]")
    ax[1].set_title("closed loop: distance from the analog-filter loop", fontsize=9)
    fig.suptitle(f"Digital filters against the analog ones, error vs control period\nmade by: {cmd}  "
                 f"(ehss-gym {__version__})", fontsize=10)
    fig.tight_layout()
    atomic_write(path, lambda f: fig.savefig(f, format="png", dpi=100))
    plt.close(fig)


def summary_lines(ol: list[dict], cl: list[dict]) -> list[str]:
    """Bullet points of the main findings, every number computed from the rows."""
    def span(vals):
        vals = [v for v in vals if np.isfinite(v)]
        if not vals:
            return "nan"
        lo, hi = f"{min(vals):.3g}", f"{max(vals):.3g}"
        return lo if lo == hi else f"{lo} to {hi}"

    hs = sorted({r["h"] for r in cl}, reverse=True)
    hr = f"h = {', '.join(_us(h) for h in hs)} us"
    out = []
    for task in TASK_ORDER:
        z = [r["ratio_analog"] for r in cl if r["task"] == task and r["scheme"] == "zoh"]
        f = [r["ratio_analog"] for r in cl if r["task"] == task and r["scheme"] == "foh"]
        sz = [100 * r["saturation"] for r in cl if r["task"] == task and r["scheme"] == "zoh"]
        sf = [100 * r["saturation"] for r in cl if r["task"] == task and r["scheme"] == "foh"]
        out.append(f"- {task}, closed loop ({hr}): RMSE over the analog loop's {span(z)} with zoh, {span(f)} with "
                   f"foh; saturated {span(sz)} % of steps with zoh, {span(sf)} % with foh.")
    zb = [r["beta_ratio"] for r in ol if r["top"] and r["scheme"] == "zoh"]
    fa = [r["alpha_ratio"] for r in ol if r["top"] and r["scheme"] == "foh"]

    def top_orders(scheme):
        keys = {(r["task"], r["filter"]) for r in ol if r["top"] and r["scheme"] == scheme}
        res = []
        for k in keys:
            rs = sorted((r for r in ol if r["top"] and r["scheme"] == scheme and (r["task"], r["filter"]) == k),
                        key=lambda r: r["h"])
            res.append(_order([r["h"] for r in rs], [r["rel_rms"] for r in rs]))
        return span(res)

    out.append(f"- Open loop, zoh: the top derivative's error is the lag term c0 (h/2) v' (fitted beta / (c0 h/2) = "
               f"{span(zb)} over both filters, both tasks and every h); observed order {top_orders('zoh')}.")
    out.append(f"- Open loop, foh: the top derivative's error is the interpolation term -c0 (h^2/12) v'' (fitted "
               f"alpha / (-c0 h^2/12) = {span(fa)}); observed order {top_orders('foh')}.")
    for task in TASK_ORDER:
        for r in ol:
            if r["task"] == task and r["filter"] == "estimator" and r["top"] and r["scheme"] == "foh" \
                    and r["h"] == max(hs):
                q = r["order"]
                pred = r["c0"] * r["h"] ** 2 * OMEGA ** (2 - q) / 12.0
                out.append(f"- {task}: foh's top estimator derivative at {_us(r['h'])} us is off by {r['rel_rms']:.3g} "
                           f"of the signal open loop (c0 h^2 w^(2-q)/12 = {pred:.3g} predicted, q = {q}): c0 = "
                           f"{r['c0']:.3g} s^-{q} multiplies the inter-sample interpolation error.")
    top = {(r["task"], r["h"]): r for r in ol if r["filter"] == "estimator" and r["top"] and r["scheme"] == "foh"}
    for task in TASK_ORDER:
        rs = [r for r in cl if r["task"] == task and r["scheme"] == "foh" and (task, r["h"]) in top]
        q = [r["dev_analog"] / (top[(task, r["h"])]["rms_err"] / _lambda0(task)) for r in rs]
        yt = [r["rms_y_top"] for r in cl if r["task"] == task and r["scheme"] != "zoh"]
        yd = [r["rms_yd_top"] for r in cl if r["task"] == task and r["scheme"] != "zoh"]
        out.append(f"- {task}, foh closed loop: RMS(e - e_analog) is {span(q)} times its quasi-static estimate; the "
                   f"plant's true y^(m-1) has an RMS of {span(yt)} rad/s^3 in the foh and analog runs, against "
                   f"{span(yd)} for the reference model's y_d^(m-1).")
    return out


def replace_block(text: str, block: str) -> str:
    """``text`` with the lines from BEGIN to END (inclusive) replaced by BEGIN, ``block``, END.

    Raises:
        ValueError: if the markers are missing, repeated or out of order.
    """
    if text.count(BEGIN) != 1 or text.count(END) != 1:
        raise ValueError(f"need exactly one {BEGIN} and one {END}")
    i = text.index(BEGIN)
    j = text.index(END)
    if j < i:
        raise ValueError(f"{END} comes before {BEGIN}")
    return text[:i] + BEGIN + "\n" + block.strip("\n") + "\n" + text[j:]


def docs_block(ol, cl, cmd: str, report_link: str) -> str:
    """The generated block for docs/MODEL.md."""
    return (f"<!-- generated: edit ehss_gym/study/fidelity.py, not this block -->\n"
            f"Made by `{cmd}` (ehss-gym {__version__}); every derivative, the reference model, the fits and "
            f"the figure: [{report_link}]({report_link}).\n\n{main_table(ol, cl)}\n\n{MAIN_LEGEND}\n")


def write_report(ol, cl, out: str, cmd: str, periods, cl_periods, t_end: float, wall: float, quick: bool,
                 docs: str | None = None) -> str:
    """Write FIDELITY.md, the CSVs and the figure under ``out``; returns FIDELITY.md's path."""
    data = os.path.join(out, "data")
    figs = os.path.join(out, "figures")
    os.makedirs(data, exist_ok=True)
    os.makedirs(figs, exist_ok=True)
    atomic_write_text(os.path.join(data, "open_loop.csv"), _csv(ol, OPEN_COLS))
    atomic_write_text(os.path.join(data, "closed_loop.csv"), _csv(cl, CLOSED_COLS))
    plot_order(ol, cl, os.path.join(figs, "order.png"), cmd)
    docs_ref = "docs/MODEL.md"
    if docs is not None:
        rel = os.path.relpath(os.path.abspath(docs), os.path.abspath(out)).replace(os.sep, "/")
        docs_ref = f"[{os.path.basename(docs)}]({rel})"
    lam_v, lam_p = _lambda0("velocity"), _lambda0("position")
    zoh_top = [r["beta_ratio"] for r in ol if r["top"] and r["scheme"] == "zoh"]
    foh_top = [r["alpha_ratio"] for r in ol if r["top"] and r["scheme"] == "foh"]
    quick_note = ("\n**QUICK MODE** (`--quick`): the closed loop runs only "
                  f"{', '.join(_us(h) for h in cl_periods)} us for {t_end:g} s; numbers are a smoke test.\n"
                  if quick else "")
    md = f"""# Fidelity of the digital filters to the analog ones

Made by `{cmd}` (ehss-gym {__version__}) in {wall:.1f} s wall time.
{quick_note}
The reference model (Butterworth, order m, 20 Hz, input r) and the output-derivative estimator
(Butterworth, order m - 1, 1 kHz, input the measured output y) are continuous filters in the paper. The
controller runs them digitally at its period h, as `Scenario(estimator=...)` selects: `zoh` (wave 1's
scheme: held input, top derivative from the current sample), `foh` (the default: first-order hold with a
feed-through term) or `analog` (the continuous filters integrated with the plant, the reference). The
derivation is in {docs_ref}, "Digital filters". m = 3 for the velocity task
(output omega), m = 4 for position (output theta).

## Main table

{main_table(ol, cl)}

{MAIN_LEGEND}

## In short (computed from the tables)

{chr(10).join(summary_lines(ol, cl))}

## Open loop: every derivative of both filters

Each digital filter is driven by the sampled v = sin(2t) (amplitude 1 in the output unit) through the
kernels' own functions (`ehss_gym.core.control.filter_outputs`, `advance_filter`,
`ehss_gym.core.filters.padded_filter(order, cutoff, h, scheme)`), started at the analog steady state; the
first {SETTLE:g} s are left out and the next {WINDOW:.4g} s (one period) compared at the samples with the
analog filter's exact steady-state response Im((jw)^i c0/P(jw) e^(jwt)), P the Butterworth polynomial.
*rel. RMS* is the RMS error over the RMS of the analog response's i-th derivative; *observed order* the
slope of log(rel. RMS) against log(h).

{open_loop_table(ol, periods)}

## Open loop: what the top derivative's error is made of

For a sine the error of the top derivative lies in the span of v' and v''; it is fitted by least squares
as err = beta v' + alpha v''. The ZOH state lags by ~h/2, which predicts beta = c0 h/2 (the lag term);
FOH's inter-sample interpolation error (on average h^2/12 v'') predicts alpha = -c0 h^2/12. For the
velocity estimator this is the fit err = a y^(i) + b y^(i-1) with b = beta; for the position estimator
(i = 3) the lag term multiplies y', not y^(i-1) = y'', so the fit is written on y' and y'' for every
filter. The literal fit err = a v^(i) + b v^(i-1) of every derivative is in `data/open_loop.csv`
(`fit_a`, `fit_b`). Over these rows beta / (c0 h/2) for ZOH lies in [{min(zoh_top):.4g}, {max(zoh_top):.4g}]
and alpha / (-c0 h^2/12) for FOH in [{min(foh_top):.4g}, {max(foh_top):.4g}].

{top_fit_table(ol)}

## Closed loop: distance from the analog loop, and what sets it

*RMS(e - e_analog)*: the RMS over the logged samples in [{T_FROM:g} s, {t_end:g} s) of e minus the
analog-filter loop's e at the same h and times. *quasi-static estimate*: the open-loop RMS error of the
estimator's top derivative on the paper's sine divided by lambda_0 (the controller holds its estimate of
s = e^(m-1) + ... + lambda_0 e near 0, so an error d in the estimated e^(m-1) that is slow against the loop
moves e by about -d/lambda_0; lambda_0 = {lam_v:.4g} s^-2 velocity, {lam_p:.4g} s^-3 position); it leaves out
the reference model's errors, the lower derivatives' and the loop's own fast motion. *max abs(e)*: the
largest logged error on the window [output unit]. *median abs(u_base)*: the median size of the Sontag
current (before the limit) on the window. *RMS of true y^(m-1)*: omega'' (velocity) or theta''' (position)
from the logged states along the model, next to the reference model's y_d^(m-1) that it tracks (a much
larger value means fast motion of the loop's own that a sine does not have). Statistics use the
trajectory log (one sample per ~1 ms); the saturation in the main table counts every control step of the run.

{closed_extra_table(ol, cl)}

{closed_order_table(cl, cl_periods)}

## Figure

![error against h](figures/order.png)

`figures/order.png`: left, the open-loop relative RMS error of each filter's top derivative (filled markers
and solid lines: estimator; open markers and dashed lines: reference model); right, the closed-loop
RMS(e - e_analog). Grey guides have slopes 1 and 2.

## Files

- `data/open_loop.csv`: one row per task, filter, scheme, h and derivative (`rms_err` in the output unit
  / s^i, `rel_rms`, the fits `fit_a`, `fit_b` of err = a v^(i) + b v^(i-1), and for the top derivative
  `beta`, `beta_ratio`, `alpha`, `alpha_ratio`).
- `data/closed_loop.csv`: one row per task, h and scheme (`rmse`, `dev_analog` in the output unit,
  `saturation` as a share, `median_psi_over_g` and `median_u_base` [mA], `rms_y_top` and `rms_yd_top`
  [rad/s^3], `max_abs_e` in the output unit, `tv_u_rate` [mA/s], `diverged`).
- `figures/order.png`.
"""
    path = os.path.join(out, "FIDELITY.md")
    atomic_write_text(path, md)
    return path


# ------------------------------------------------------------------------------------------------
# CLI
# ------------------------------------------------------------------------------------------------


def run(out: str = "reports/fidelity", docs: str | None = "docs/MODEL.md", quick: bool = False,
        progress: bool = True, cmd: str = PROG) -> str:
    """Compute everything and write the report (and the docs block); returns FIDELITY.md's path.

    Args:
        out: report folder.
        docs: markdown file whose marker block gets the main table; None = leave docs alone.
        quick: closed loop at 30 and 10 us only, for QUICK_T_END s (the open loop is the same; it is cheap).
        progress: show a tqdm bar on stderr.
        cmd: the command line to print in the outputs.

    Raises:
        ValueError: if ``docs`` has no marker block (checked before any work).
    """
    from tqdm import tqdm

    t0 = time.perf_counter()
    doc_text = None
    if docs is not None:
        with open(docs, encoding="utf-8") as f:
            doc_text = f.read()
        replace_block(doc_text, "")  # fail early on missing markers
    # the closed loop also at the env's default period (the check "and at the new default period")
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
    path = write_report(ol, cl, out, cmd, PERIODS, cl_periods, t_end, time.perf_counter() - t0, quick, docs)
    if doc_text is not None:
        link = os.path.relpath(path, os.path.dirname(os.path.abspath(docs)) or ".").replace(os.sep, "/")
        atomic_write_text(docs, replace_block(doc_text, docs_block(ol, cl, cmd, link)))
    return path
