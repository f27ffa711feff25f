"""Memory: peak resident set of a large batch of trajectories against the size of the data itself.

Measured in a fresh subprocess (``python -m benchmarks.bench_memory --child ...``) so
nothing else in the benchmark run inflates it: the child imports ehss_gym, runs a
tiny warm-up batch (kernels loaded, thread pool started), reads its peak RSS
(``resource.getrusage(...).ru_maxrss``) as the baseline, runs the batch, and reads
the peak again. The data size is the sum of ``nbytes`` of every returned
trajectory's arrays (log and metrics accumulator).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time

from .common import Section, Table, log, repo_root

N_LOG_COLUMNS = 26  # ehss_gym.core.layout.N_LOG, repeated here so the parent need not import the package


def _mem_available() -> int | None:
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def _current_rss() -> int:
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except OSError:
        return -1


def child(n: int, t_end: float, log_interval: float) -> dict:
    """Run in the subprocess: returns the measurements as a dict."""
    from ehss_gym import Scenario, simulate_batch

    base = Scenario(task="velocity", sigma=1e5, smoothing=1e3, current_limit=10.0, t_end=t_end,
                    log_interval=log_interval)
    simulate_batch([base.replace(t_end=0.01)] * 2)
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    cur0 = _current_rss()
    scenarios = [base.replace(n=(2, 4, 6)[i % 3]) for i in range(n)]
    t0 = time.perf_counter()
    trajs = simulate_batch(scenarios)
    dt = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    data = sum(tr.log.nbytes + tr.acc.nbytes for tr in trajs)
    rows = trajs[0].log.shape[0]
    return {"n": n, "t_end": t_end, "log_interval": log_interval, "rows": rows, "baseline_peak_rss": rss0,
            "baseline_rss": cur0, "peak_rss": peak, "rss_after": _current_rss(), "data_bytes": data, "seconds": dt,
            "substeps": n * scenarios[0].n_steps * scenarios[0].substeps}


def measure(n: int, t_end: float, log_interval: float) -> dict:
    cmd = [sys.executable, "-m", "benchmarks.bench_memory", "--child", str(n), str(t_end), str(log_interval)]
    out = subprocess.run(cmd, cwd=repo_root(), capture_output=True, text=True, timeout=3600)
    if out.returncode != 0:
        raise RuntimeError(f"memory child failed ({out.returncode}): {out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def run(quick: bool) -> Section:
    sec = Section("memory", "4. Memory: peak RSS of a batch vs the size of its trajectories")
    n, t_end = (16, 1.0) if quick else (1024, 20.0)
    log_interval = 1e-3
    data_est = n * round(t_end / log_interval) * N_LOG_COLUMNS * 8
    avail = _mem_available()
    # simulate_batch holds the batch log and the per-trajectory copies at once: ~2x the data
    if avail is not None and 2.5 * data_est > 0.6 * avail:
        log_interval = 1e-2
        sec.note(f"MemAvailable {avail / 2**30:.1f} GiB is too little for {n} x {t_end:g} s logged every 1 ms "
                 f"(~{2 * data_est / 2**30:.1f} GiB at peak), so this run logs every 10 ms.")
    if quick:
        sec.note(f"--quick: {n} scenarios x {t_end:g} s instead of 1024 x 20 s.")
    log(f"memory: {n} x {t_end:g} s (log every {log_interval:g} s) in a subprocess")
    r = measure(n, t_end, log_interval)
    tb = Table("memory", f"Peak resident memory, batch of {n} velocity scenarios x {t_end:g} s (h = 1e-4 s, "
                         f"log every {log_interval * 1e3:g} ms, {N_LOG_COLUMNS} float64 columns)",
               ["quantity", "MiB", "x_data"])
    mib = 2.0 ** 20
    d = r["data_bytes"]
    tb.add("trajectory data returned (sum of array nbytes)", d / mib, 1.0)
    tb.add("peak RSS before the batch (import, warm-up)", r["baseline_peak_rss"] / mib, r["baseline_peak_rss"] / d)
    tb.add("peak RSS of the process", r["peak_rss"] / mib, r["peak_rss"] / d)
    tb.add("peak RSS increase due to the batch", (r["peak_rss"] - r["baseline_peak_rss"]) / mib,
           (r["peak_rss"] - r["baseline_peak_rss"]) / d)
    tb.add("RSS after the batch (trajectories held)", r["rss_after"] / mib, r["rss_after"] / d)
    sec.tables.append(tb)
    inc = (r["peak_rss"] - r["baseline_peak_rss"]) / d
    sec.note(f"The batch took {r['seconds']:.1f} s ({r['substeps'] / r['seconds'] / 1e6:.3g} M plant substeps/s on "
             f"all threads). Its peak RSS increase is {inc:.2f}x the data. Expected from the code: simulate_batch "
             f"fills one (scenarios, rows, {N_LOG_COLUMNS}) log array in the compiled call, then copies each "
             f"trajectory's rows out of it while that array is alive, so ~2x the data is resident at the peak; "
             f"the per-lane working arrays are a few hundred bytes per scenario.")
    return sec


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description="memory benchmark child")
    p.add_argument("--child", nargs=3, metavar=("N", "T_END", "LOG_INTERVAL"), required=True)
    a = p.parse_args(argv)
    n, t_end, li = int(a.child[0]), float(a.child[1]), float(a.child[2])
    print(json.dumps(child(n, t_end, li)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
