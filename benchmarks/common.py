"""Shared benchmark machinery: interleaved timing, machine description, tables and targets."""

from __future__ import annotations

import csv
import io
import math
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib import metadata

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


def wall_target_line(res: dict, target_s: float, cores: int) -> str:
    """'target <= T s wall on N cores: met/MISSED' for a :func:`time_command` result, flagging a shared machine."""
    ok = res["wall_s"] <= target_s
    return (f"target <= {target_s:.0f} s wall on {cores} cores: {'met' if ok else 'MISSED'}"
            + ("" if res["load_before"] < 0.5 else " (machine shared: other load was running)"))


def median(xs) -> float:
    return float(statistics.median(xs))


def spread(xs) -> str:
    """'min..max' of a sample, for the tables."""
    return f"{fmt(min(xs))}..{fmt(max(xs))}"


def fmt(x, digits: int = 3) -> str:
    """Compact number formatting for tables."""
    if x is None:
        return "-"
    if isinstance(x, str):
        return x
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, int):
        return str(x)
    if not math.isfinite(x):
        return str(x)
    if x == 0:
        return "0"
    a = abs(x)
    if a >= 1e6 or a < 1e-3:
        return f"{x:.{digits - 1}e}"
    return f"{x:.{digits}g}" if a < 1000 else f"{x:,.0f}"


@dataclass
class Table:
    """A result table: written as ``<name>.csv`` and as a markdown table in PERF.md."""

    name: str
    title: str
    columns: list[str]
    rows: list[list] = field(default_factory=list)

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
    """One benchmark's results: tables, targets and markdown notes (incl. its profile)."""

    key: str
    title: str
    tables: list[Table] = field(default_factory=list)
    targets: list[Target] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
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
    import numba

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
