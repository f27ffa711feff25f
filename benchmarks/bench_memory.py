"""Memory: peak resident set of a large batch of trajectories against the size of the data itself.

Measured in a fresh subprocess (``python -m benchmarks.bench_memory --child N T_END LOG_INTERVAL``) so
nothing else in the benchmark run inflates it: the child imports ehss_gym, runs a
tiny warm-up batch (kernels loaded, thread pool started), resets its peak RSS to the
RSS then (:func:`benchmarks.common.reset_peak_rss`: Linux keeps the high-water mark
across exec, so the child would otherwise start with this benchmark process's peak),
reads it as the baseline, runs the batch, and reads the peak again. The data size is the
sum of ``nbytes`` of every returned trajectory's arrays (log and metrics accumulator).
"""

from __future__ import annotations

import sys
import time

from ehss_gym import Scenario, simulate_batch
from ehss_gym.core.layout import N_LOG

from . import lane_memory
from .common import Section, Table, child_main, current_rss, log, peak_rss, proc_kib_field, reset_peak_rss, run_child

SCENARIO = dict(task="velocity", sigma=1e5, smoothing=1e3, current_limit=10.0)  # n = 2, 4, 6 in turn
FULL = (1024, 20.0)  # scenarios, simulated time [s] of the full run
QUICK = (16, 1.0)  # ... and of --quick
LOG_INTERVAL = 1e-3  # [s]
LOW_MEMORY_LOG_INTERVAL = 1e-2  # [s] when the 1 ms log would not fit in the available memory


def child(n: int, t_end: float, log_interval: float) -> dict:
    """Run in the subprocess: returns the measurements as a dict."""
    base = Scenario(**SCENARIO, t_end=t_end, log_interval=log_interval)
    simulate_batch([base.replace(t_end=0.01)] * 2)
    reset = reset_peak_rss()
    rss0 = peak_rss()
    cur0 = current_rss()
    scenarios = [base.replace(n=(2, 4, 6)[i % 3]) for i in range(n)]
    t0 = time.perf_counter()
    trajs = simulate_batch(scenarios)
    dt = time.perf_counter() - t0
    peak = peak_rss()
    data = sum(tr.log.nbytes + tr.acc.nbytes for tr in trajs)
    rows = trajs[0].log.shape[0]
    return {"n": n, "t_end": t_end, "log_interval": log_interval, "rows": rows, "baseline_peak_rss": rss0,
            "baseline_rss": cur0, "peak_rss": peak, "rss_after": current_rss(), "data_bytes": data, "seconds": dt,
            "substeps": n * scenarios[0].n_steps * scenarios[0].substeps, "peak_reset": reset}


def measure(n: int, t_end: float, log_interval: float) -> dict:
    """:func:`child` in a fresh process."""
    return run_child("bench_memory", [n, t_end, log_interval], timeout=3600)


def _data_estimate(n: int, t_end: float) -> int:
    """[bytes] of the logs of n scenarios of t_end [s] logged every LOG_INTERVAL."""
    return n * round(t_end / LOG_INTERVAL) * N_LOG * 8


def run(quick: bool) -> Section:
    """Section 4: peak RSS of a large batch against the size of its trajectories, in a fresh process."""
    sec = Section("memory", "4. Memory: peak RSS of a batch vs the size of its trajectories", template="memory.md.j2")
    n, t_end = QUICK if quick else FULL
    data_est = _data_estimate(n, t_end)
    avail = proc_kib_field("/proc/meminfo", "MemAvailable")
    # the batch's log is resident once (each trajectory is a view of its rows); the margin leaves room for the rest
    low_memory = avail is not None and 2.5 * data_est > 0.6 * avail
    log_interval = LOW_MEMORY_LOG_INTERVAL if low_memory else LOG_INTERVAL
    log(f"memory: {n} x {t_end:g} s (log every {log_interval:g} s) in a subprocess")
    r = measure(n, t_end, log_interval)
    sec.tables.append(memory_table(r))
    sec.context = report_context(quick, (n, t_end), log_interval, avail if low_memory else None, r)
    log(f"memory: the vector env at {' and '.join(map(str, lane_memory.SIZES))} sub-envs, each in a subprocess")
    lanes = lane_memory.measure()
    log("memory: vector env children " + "; ".join(f"{r['n']} sub-envs: RSS {r['baseline_rss'] / 2**20:.1f} -> "
                                                   f"{r['rss'] / 2**20:.1f} MiB" for r in lanes["runs"]))
    sec.tables.append(lane_table(lanes))
    return sec


def report_context(quick: bool, batch: tuple[int, float], log_interval: float, avail: int | None, r: dict) -> dict:
    """What ``memory.md.j2`` is rendered with.

    Args:
        quick: whether this is the --quick run.
        batch: its scenarios and their simulated time [s].
        log_interval: the log interval the batch ran with [s].
        avail: MemAvailable [bytes] when it was too little for the 1 ms log (so the batch logged less often), else
            None.
        r: :func:`child`'s measurements.
    """
    n, t_end = batch
    data_est = _data_estimate(n, t_end)
    return {
        "quick": quick, "n": n, "t_end": t_end, "full": FULL, "log_columns": N_LOG,
        "h": Scenario(**SCENARIO).control_period, "log_ms": log_interval * 1e3,
        "low_memory": None if avail is None else {"avail_gib": avail / 2**30, "peak_gib": 2 * data_est / 2**30,
                                                  "log_ms": LOG_INTERVAL * 1e3,
                                                  "fallback_ms": LOW_MEMORY_LOG_INTERVAL * 1e3},
        "seconds": r["seconds"], "rate_M": r["substeps"] / r["seconds"] / 1e6,
        "increase": (r["peak_rss"] - r["baseline_peak_rss"]) / r["data_bytes"],
        "lanes": {"sizes": lane_memory.SIZES, "steps": lane_memory.AGENT_STEPS,
                  "episode_s": lane_memory.EPISODE_SECONDS},
    }


def memory_table(r: dict) -> Table:
    """The child's peak and current RSS in MiB and as multiples of the trajectory data it returned."""
    tb = Table("memory", columns=["quantity", "MiB", "x_data"])
    mib = 2.0 ** 20
    d = r["data_bytes"]
    tb.add("trajectory data returned (sum of array nbytes)", d / mib, 1.0)
    tb.add("RSS before the batch (import and warm-up done; the peak is reset to it)", r["baseline_peak_rss"] / mib,
           r["baseline_peak_rss"] / d)
    tb.add("peak RSS of the process", r["peak_rss"] / mib, r["peak_rss"] / d)
    tb.add("peak RSS increase due to the batch", (r["peak_rss"] - r["baseline_peak_rss"]) / mib,
           (r["peak_rss"] - r["baseline_peak_rss"]) / d)
    tb.add("RSS after the batch (trajectories held)", r["rss_after"] / mib, r["rss_after"] / d)
    return tb


def lane_table(r: dict) -> Table:
    """The vector env's memory per sub-env [KiB]: its buffers, the resident set it holds and the peak it adds
    (:mod:`lane_memory`)."""
    tb = Table("memory_per_lane", columns=["quantity", "KiB_per_sub_env"])
    tb.add("the env's buffers (sum of the arrays it owns)", r["buffers_per_lane"] / 1024.0)
    tb.add("resident set the env holds after its steps", r["rss_per_lane"] / 1024.0)
    tb.add("peak resident set the env adds (its steps' results included)", r["peak_per_lane"] / 1024.0)
    return tb


def main(argv=None) -> int:
    return child_main(child, {"N": int, "T_END": float, "LOG_INTERVAL": float}, "memory benchmark child", argv)


if __name__ == "__main__":
    sys.exit(main())
