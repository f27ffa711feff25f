"""Shared benchmark machinery: interleaved timing, child processes, profiles, machine description, tables, targets."""

from __future__ import annotations

import argparse
import cProfile
import csv
import io
import json
import math
import os
import platform
import pstats
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib import metadata

import numba

from ehss_gym.infra.fmt import fmt_cell

PACKAGES = ("ehss-gym", "numpy", "numba", "llvmlite", "scipy", "gymnasium", "stable-baselines3", "torch",
            "gym-electric-motor")


def log(msg: str) -> None:
    """Progress line on stderr (the report goes to files)."""
    print(f"[bench {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def interleave(cases: dict[str, Callable[[], float | None]], repeats: int) -> dict[str, list[float]]:
    """Time each case ``repeats`` times, interleaved A B A B ... so drift and load hit all alike.

    A case's wall time is taken, unless it returns a ``float``: then that is its own
    measured time [s] (when set-up must be left out of the timing).

    Returns:
        case name -> list of times [s], one per repeat.
    """
    times: dict[str, list[float]] = {k: [] for k in cases}
    for _ in range(repeats):
        for name, fn in cases.items():
            t0 = time.perf_counter()
            out = fn()
            dt = time.perf_counter() - t0
            times[name].append(out if isinstance(out, float) else dt)
    return times


def time_command(subcommand: str, out_name: str, args: list) -> dict:
    """Run ``ehss <subcommand> --out <tmp>/<out_name> --no-progress <args>`` once in a fresh process, into a
    temporary folder deleted afterwards.

    Returns:
        dict: wall_s and cpu_s [s] (user + system of the child and its workers), load_before / load_after
        (1-min load averages) and stdout. Raises RuntimeError if the command fails.
    """
    with tempfile.TemporaryDirectory(prefix=f"bench-{subcommand}-") as tmp:
        cmd = [sys.executable, "-m", "ehss_gym.cli", subcommand, "--out", os.path.join(tmp, out_name),
               "--no-progress", *args]
        load0 = os.getloadavg()
        r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        load1 = os.getloadavg()
        if proc.returncode != 0:
            raise RuntimeError(f"ehss {subcommand} failed ({proc.returncode}):\n{proc.stderr[-2000:]}")
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    return {"wall_s": wall, "cpu_s": cpu, "load_before": load0[0], "load_after": load1[0], "stdout": proc.stdout}


def run_child(module: str, args: list, env: dict | None = None, timeout: float = 600.0) -> dict:
    """Run ``python -m benchmarks.<module> --child <args>`` in a fresh process from the checkout root.

    Args:
        module: the benchmark module whose :func:`child_main` (or own ``--child`` entry point) runs the child.
        args: the values after ``--child``.
        env: the child's environment (default: this process's).
        timeout: [s] before the child is killed.

    Returns:
        dict: the JSON object the child printed last, plus ``wall_s`` [s], the whole subprocess's wall time
        (interpreter start and exit included). Raises RuntimeError if the child fails.
    """
    cmd = [sys.executable, "-m", f"benchmarks.{module}", "--child", *map(str, args)]
    t0 = time.perf_counter()
    p = subprocess.run(cmd, cwd=repo_root(), env=env, capture_output=True, text=True, timeout=timeout)
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        raise RuntimeError(f"benchmark child `{' '.join(cmd[1:])}` failed ({p.returncode}):\n{p.stderr[-2000:]}")
    return {**json.loads(p.stdout.strip().splitlines()[-1]), "wall_s": wall}


def proc_kib_field(path: str, key: str) -> int | None:
    """[bytes] of a "key: N kB" line of a /proc file (``/proc/meminfo``, ``/proc/self/status``); None if absent."""
    try:
        with open(path) as f:
            for line in f:
                if line.startswith(key + ":"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def current_rss() -> int:
    """This process's resident set now [bytes] (``/proc/self/statm``), -1 where it cannot be read."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except OSError:
        return -1


def reset_peak_rss() -> bool:
    """Reset this process's peak resident set (VmHWM) to its current size, through /proc/self/clear_refs (Linux 4.0
    on). A child needs it before it measures a peak: Linux keeps the high-water mark across exec, so a child started
    by a large process (this benchmark's, with torch loaded) would otherwise report the parent's peak. Returns False
    where it is not possible (then :func:`peak_rss` includes what came before)."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def peak_rss() -> int:
    """This process's peak resident set [bytes]: VmHWM (which :func:`reset_peak_rss` resets), else ru_maxrss."""
    hwm = proc_kib_field("/proc/self/status", "VmHWM")
    return hwm if hwm is not None else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def child_main(fn: Callable[..., dict], types: dict[str, type], description: str, argv=None) -> int:
    """The ``--child`` entry point of a benchmark module: calls ``fn`` and prints its result as one JSON line.

    Args:
        fn: the measurement, called with the ``--child`` values converted by ``types``.
        types: metavar -> type of each value after ``--child``, in order.
        description: for ``--help``.
        argv: the arguments (default: ``sys.argv[1:]``).
    """
    p = argparse.ArgumentParser(description=description)
    p.add_argument("--child", nargs=len(types), metavar=tuple(types), required=True)
    values = p.parse_args(argv).child
    print(json.dumps(fn(*(t(v) for t, v in zip(types.values(), values)))))
    return 0


def profile(fn: Callable, *args) -> pstats.Stats:
    """cProfile statistics of the one call ``fn(*args)``."""
    prof = cProfile.Profile()
    prof.enable()
    fn(*args)
    prof.disable()
    return pstats.Stats(prof)


def top_own_time(st: pstats.Stats, top: int = 8, strip: tuple[str, ...] = ("site-packages/",)
                 ) -> tuple[float, list[tuple[float, str]]]:
    """The total own time [s] of a profile and its ``top`` functions by own time.

    Args:
        st: the profile.
        top: how many functions.
        strip: each file name is cut after the last occurrence of each of these, in turn (so that
            ``.../site-packages/numpy/x.py`` reads ``numpy/x.py``).

    Returns:
        (total own time [s], [(share of the total, "file:line(function)"), ...] largest share first).
    """
    total = sum(v[2] for v in st.stats.values())  # tottime over all functions
    rows = []
    for (file, line, func), v in st.stats.items():
        for prefix in strip:
            file = file.split(prefix)[-1]
        rows.append((v[2] / total, f"{file}:{line}({func})"))
    return total, sorted(rows, reverse=True)[:top]


def median(xs) -> float:
    return float(statistics.median(xs))


def spread(xs) -> str:
    """'min..max' of a sample, for the tables."""
    return f"{fmt(min(xs))}..{fmt(max(xs))}"


def fmt(x, digits: int = 3) -> str:
    """A table cell (:func:`ehss_gym.infra.fmt.fmt_cell`): thousands grouped from 1000, scientific from 1e6."""
    return fmt_cell(x, digits, sci_from=1e6, grouped_from=1000)

@dataclass
class Table:
    """A result table: written as ``<name>.csv`` and as a markdown table in PERF.md.

    A section rendered from its own template gives the table's caption there and leaves ``title`` empty;
    ``title`` is the caption of sections without a template.
    """

    name: str
    title: str = ""
    columns: list[str] = field(default_factory=list)
    rows: list[list] = field(default_factory=list)

    def __post_init__(self):
        if not self.columns:
            raise ValueError(f"table {self.name}: no columns")

    def add(self, *row) -> None:
        if len(row) != len(self.columns):
            raise ValueError(f"table {self.name}: row has {len(row)} cells, expected {len(self.columns)}")
        self.rows.append(list(row))

    def csv_text(self) -> str:
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(self.columns)
        for r in self.rows:
            w.writerow([repr(c) if isinstance(c, float) else c for c in r])
        return buf.getvalue()

    def markdown(self) -> str:
        head = "| " + " | ".join(self.columns) + " |"
        sep = "| " + " | ".join("---" for _ in self.columns) + " |"
        body = ["| " + " | ".join(fmt(c) for c in r) + " |" for r in self.rows]
        return "\n".join([head, sep, *body])


@dataclass
class Target:
    """A speed target: ``measured`` compared with ``goal`` (>= unless ``lower_is_better``)."""

    name: str
    measured: float | None
    goal: float
    unit: str = "x"
    lower_is_better: bool = False
    note: str = ""

    @property
    def status(self) -> str:
        if self.measured is None or not math.isfinite(self.measured):
            return "not measured"
        ok = self.measured <= self.goal if self.lower_is_better else self.measured >= self.goal
        return "hit" if ok else "MISS"

    @property
    def shortfall(self) -> str:
        """How far from the goal, as a factor (only for a miss)."""
        if self.status != "MISS":
            return ""
        f = self.measured / self.goal if self.lower_is_better else self.goal / self.measured
        return f"{f:.3g}x short"


@dataclass
class Section:
    """One benchmark's results: tables, targets, and what the report says about them.

    A section either names its ``template`` (a file under ``benchmarks/templates``) and the numbers it
    needs in ``context``, or carries ready markdown ``notes``; see :mod:`benchmarks.report`.
    """

    key: str
    title: str
    tables: list[Table] = field(default_factory=list)
    targets: list[Target] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    template: str = ""
    context: dict = field(default_factory=dict)
    skipped: str = ""
    seconds: float = 0.0
    load_before: tuple = ()
    load_after: tuple = ()

    def note(self, text: str) -> None:
        self.notes.append(text)


def load_average() -> tuple[float, float, float]:
    try:
        return tuple(round(v, 2) for v in os.getloadavg())
    except OSError:  # pragma: no cover - non-Unix
        return (math.nan, math.nan, math.nan)


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            info = f.read()
    except OSError:
        return platform.processor() or "unknown"
    fields = {}
    for line in info.splitlines():
        if ":" in line:
            k, v = (s.strip() for s in line.split(":", 1))
            fields.setdefault(k, v)
    name = fields.get("model name", "unknown")
    fam, mod = fields.get("cpu family"), fields.get("model")
    flags = fields.get("flags", "").split()
    simd = "avx512f" if "avx512f" in flags else "avx2" if "avx2" in flags else "sse"
    return f"{name} (family {fam}, model {mod}, widest SIMD {simd})"


def versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for p in PACKAGES:
        try:
            out[p] = metadata.version(p)
        except metadata.PackageNotFoundError:
            out[p] = "not installed"
    return out


def machine() -> dict:
    try:
        affinity = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover
        affinity = os.cpu_count()
    try:
        with open("/proc/meminfo") as f:
            mem = {ln.split(":")[0]: ln.split(":")[1].strip() for ln in f}
        mem_total = mem.get("MemTotal", "?")
    except OSError:
        mem_total = "?"
    return {
        "cpu": cpu_model(),
        "logical cores": os.cpu_count(),
        "cores usable by this process": affinity,
        "numba threads (default)": numba.config.NUMBA_NUM_THREADS,
        "memory": mem_total,
        "os": platform.platform(),
    }


def repo_root() -> str:
    return os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
