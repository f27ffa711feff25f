"""The fidelity study's report: tables, the figure and FIDELITY.md (prose in templates/fidelity.md.j2).

The measurements are :mod:`ehss_gym.study.fidelity`'s; :func:`write_report` writes ``FIDELITY.md``,
``data/*.csv`` and ``figures/order.png``, and :func:`docs_block` the generated table of docs/MODEL.md.
"""

from __future__ import annotations

import csv
import io
import math
import os

import numpy as np
from matplotlib.ticker import NullFormatter, ScalarFormatter

from ehss_gym._version import __version__
from ehss_gym.core.settings import UNITS
from ehss_gym.infra.util import atomic_write, atomic_write_text
from ehss_gym.study.fidelity import (
    OMEGA,
    SCHEMES,
    SETTLE,
    T_FROM,
    TASK_ORDER,
    WINDOW,
    lambda0,
    observed_order,
)

from .render import render
from .trajectory_figures import plt

BEGIN = "<!-- fidelity-table:begin -->"
END = "<!-- fidelity-table:end -->"


def _g(x: float, digits: int = 3) -> str:
    """A number for a table: 3 significant digits, 'nan' kept visible."""
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "nan"
    return f"{x:.{digits}g}"


def _us(h: float) -> str:
    return f"{h * 1e6:g}"


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


def _top_derivative_rows(ol: list[dict]) -> dict:
    """The open-loop rows of the estimators' top derivative, by (task, scheme, h): what the closed-loop tables
    put next to each loop."""
    return {(r["task"], r["scheme"], r["h"]): r for r in ol if r["filter"] == "estimator" and r["top"]}


def _header(*cols: str, align: str) -> list[str]:
    """A markdown table's header and alignment rows; ``align`` has one letter per column (l left, r right)."""
    return ["| " + " | ".join(cols) + " |", "| " + " | ".join("---:" if a == "r" else "---" for a in align) + " |"]


def main_table(ol: list[dict], cl: list[dict]) -> str:
    """The main table (markdown): per task, h and scheme, the open-loop top-derivative error and the closed loop."""
    top = _top_derivative_rows(ol)
    lines = _header("task", "h [us]", "scheme", "open-loop top-derivative error (rel. RMS)", "bias / (c0 h/2)", "RMSE",
                    "/ analog", "RMS(e - e_analog)", "saturated [%]", "median abs(psi/G) [mA]", align="lrlrrrrrrr")
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
                     + f" | {observed_order(periods, vals):.2f} |")
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


def closed_extra_table(ol: list[dict], cl: list[dict]) -> str:
    """Closed-loop distance from the analog loop against its quasi-static estimate, and more columns."""
    top = _top_derivative_rows(ol)
    lines = _header("task", "h [us]", "scheme", "RMS(e - e_analog)", "quasi-static estimate", "measured / estimate",
                    "max abs(e)", "median abs(u_base) [mA]", "RMS of true y^(m-1) [rad/s^3]",
                    "RMS of y_d^(m-1) [rad/s^3]", align="lrlrrrrrrr")
    for r in cl:
        o = top.get((r["task"], r["scheme"], r["h"]))
        if r["scheme"] == "analog" or o is None:
            dev = est = ratio = "(reference)"
        else:
            e = o["rms_err"] / lambda0(r["task"])
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
            lines.append(f"| {task} | {est} | {observed_order(periods, [rs[h]['dev_analog'] for h in periods]):.2f} |")
    return "\n".join(lines)


def plot_observed_order(ol: list[dict], cl: list[dict], path: str, cmd: str) -> None:
    """Log-log error against h with reference slopes 1 and 2: open loop (top derivatives) and closed loop."""
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


def _span(vals) -> str:
    """'lo to hi' of the finite values at 3 significant digits ('nan' if none)."""
    vals = [v for v in vals if np.isfinite(v)]
    if not vals:
        return "nan"
    lo, hi = f"{min(vals):.3g}", f"{max(vals):.3g}"
    return lo if lo == hi else f"{lo} to {hi}"


def _top_orders(ol: list[dict], scheme: str) -> str:
    keys = {(r["task"], r["filter"]) for r in ol if r["top"] and r["scheme"] == scheme}
    res = []
    for k in keys:
        rs = sorted((r for r in ol if r["top"] and r["scheme"] == scheme and (r["task"], r["filter"]) == k),
                    key=lambda r: r["h"])
        res.append(observed_order([r["h"] for r in rs], [r["rel_rms"] for r in rs]))
    return _span(res)


def summary(ol: list[dict], cl: list[dict]) -> dict:
    """The numbers of the report's summary bullets, formatted (the prose is in the template)."""
    hs = sorted({r["h"] for r in cl}, reverse=True)
    out = {"hs": ", ".join(_us(h) for h in hs), "tasks": []}
    top = {(r["task"], r["h"]): r for r in ol if r["filter"] == "estimator" and r["top"] and r["scheme"] == "foh"}
    for task in TASK_ORDER:
        sel = {s: [r for r in cl if r["task"] == task and r["scheme"] == s] for s in ("zoh", "foh")}
        # the longest open-loop period (the closed loop may also run at the env's period, which the open loop
        # does not: an earlier version of this report looked that one up and so dropped these bullets)
        o = next((r for r in ol if r["task"] == task and r["filter"] == "estimator" and r["top"]
                  and r["scheme"] == "foh" and r["h"] == max(x["h"] for x in ol)), None)
        rs = [r for r in sel["foh"] if (task, r["h"]) in top]
        out["tasks"].append({
            "task": task,
            "ratio_zoh": _span([r["ratio_analog"] for r in sel["zoh"]]),
            "ratio_foh": _span([r["ratio_analog"] for r in sel["foh"]]),
            "sat_zoh": _span([100 * r["saturation"] for r in sel["zoh"]]),
            "sat_foh": _span([100 * r["saturation"] for r in sel["foh"]]),
            "top": None if o is None else {
                "h": _us(o["h"]), "rel_rms": f"{o['rel_rms']:.3g}", "q": o["order"], "c0": f"{o['c0']:.3g}",
                "pred": f"{o['c0'] * o['h'] ** 2 * OMEGA ** (2 - o['order']) / 12.0:.3g}"},
            "quasi": _span([r["dev_analog"] / (top[(task, r["h"])]["rms_err"] / lambda0(task)) for r in rs]),
            "y_top": _span([r["rms_y_top"] for r in cl if r["task"] == task and r["scheme"] != "zoh"]),
            "yd_top": _span([r["rms_yd_top"] for r in cl if r["task"] == task and r["scheme"] != "zoh"])})
    out["zoh_beta"] = _span([r["beta_ratio"] for r in ol if r["top"] and r["scheme"] == "zoh"])
    out["foh_alpha"] = _span([r["alpha_ratio"] for r in ol if r["top"] and r["scheme"] == "foh"])
    out["zoh_order"] = _top_orders(ol, "zoh")
    out["foh_order"] = _top_orders(ol, "foh")
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
    return render("fidelity_docs_block.md.j2", cmd=cmd, version=__version__, report_link=report_link,
                  main_table=main_table(ol, cl), main_legend=MAIN_LEGEND)


def write_report(ol, cl, out: str, cmd: str, periods, cl_periods, t_end: float, wall: float, quick: bool,
                 docs: str | None = None) -> str:
    """Write FIDELITY.md, the CSVs and the figure under ``out``; returns FIDELITY.md's path."""
    data = os.path.join(out, "data")
    figs = os.path.join(out, "figures")
    os.makedirs(data, exist_ok=True)
    os.makedirs(figs, exist_ok=True)
    atomic_write_text(os.path.join(data, "open_loop.csv"), _csv(ol, OPEN_COLS))
    atomic_write_text(os.path.join(data, "closed_loop.csv"), _csv(cl, CLOSED_COLS))
    plot_observed_order(ol, cl, os.path.join(figs, "order.png"), cmd)
    docs_ref = "docs/MODEL.md"
    if docs is not None:
        rel = os.path.relpath(os.path.abspath(docs), os.path.abspath(out)).replace(os.sep, "/")
        docs_ref = f"[{os.path.basename(docs)}]({rel})"
    lam_v, lam_p = lambda0("velocity"), lambda0("position")
    zoh_top = [r["beta_ratio"] for r in ol if r["top"] and r["scheme"] == "zoh"]
    foh_top = [r["alpha_ratio"] for r in ol if r["top"] and r["scheme"] == "foh"]
    md = render("fidelity.md.j2", cmd=cmd, version=__version__, wall=wall, quick=quick, t_end=t_end,
                cl_periods=[_us(h) for h in cl_periods], docs_ref=docs_ref, main_table=main_table(ol, cl),
                main_legend=MAIN_LEGEND, summary=summary(ol, cl), settle=SETTLE, window=WINDOW, t_from=T_FROM,
                open_loop_table=open_loop_table(ol, periods), top_fit_table=top_fit_table(ol),
                zoh_top=(min(zoh_top), max(zoh_top)), foh_top=(min(foh_top), max(foh_top)), lam_v=lam_v,
                lam_p=lam_p, closed_extra_table=closed_extra_table(ol, cl),
                closed_order_table=closed_order_table(cl, cl_periods))
    path = os.path.join(out, "FIDELITY.md")
    atomic_write_text(path, md)
    return path


