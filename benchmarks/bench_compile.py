"""Compile time: numba JIT cost on the first call, with an empty cache and with the cache warm.

Each measurement is a fresh Python subprocess (``python -m benchmarks.compile_child --child MODE``, see
:mod:`benchmarks.compile_child` for the modes) with ``NUMBA_CACHE_DIR`` pointing at a new temporary folder: the
first process compiles everything (cold), the second loads the cached machine code (warm). Cold and warm
alternate, one fresh folder per repeat. The env mode's whole subprocess wall time (interpreter start included) is
the "warm-cache import plus first step" of the targets.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile

from . import bench_env
from .common import Section, Table, Target, interleave, log, median, repo_root, run_child, spread

TARGET_WARM_S = 2.0
TARGET_NAME = "warm-cache import + gym.make + reset + first step (fresh process)"


def run(quick: bool) -> Section:
    """Section 5: start-up in fresh processes with a cold and a warm numba cache, and where the import goes."""
    sec = Section("compile", "5. Compile time: numba JIT cold vs warm cache", template="compile.md.j2")
    env_status = bench_env.env_status()
    results, times = start_up_runs(quick, env_ok=not env_status)
    sec.tables.append(compile_table(results, times))
    warm_env = None if env_status else median(times["env, warm cache"])
    sec.targets.append(Target(TARGET_NAME, warm_env, TARGET_WARM_S, unit="s", lower_is_better=True,
                              note="env not available" if env_status else ""))
    sec.context = report_context(quick, env_status, results, warm_env, import_profile())
    return sec


def report_context(quick: bool, env_status: str, results: dict[str, list[dict]], warm_env: float | None,
                   imports: list[tuple[int, str]]) -> dict:
    """What ``compile.md.j2`` is rendered with.

    Args:
        quick: whether this is the --quick run (no cold runs).
        env_status: why the env is left out, or ''.
        results: :func:`start_up_runs`'s child timings per case.
        warm_env: the median warm env start-up [s] (None when left out).
        imports: :func:`import_profile`.
    """
    return {"quick": quick, "env_status": env_status, "jit": jit_cost(results),
            "warm_miss": warm_miss(results, warm_env), "imports": [(name, us / 1e6) for us, name in imports]}


def start_up_runs(quick: bool, env_ok: bool) -> tuple[dict[str, list[dict]], dict[str, list[float]]]:
    """The fresh-process runs, interleaved: sim and env modes, cold (not with --quick) and warm.

    --quick has no cold runs: the warm runs use the package's own (default) cache.

    Returns:
        per case, the children's timings (:func:`benchmarks.compile_child.child`) and the subprocess wall times [s].
    """
    reps = 1 if quick else 2
    results: dict[str, list[dict]] = {}
    dirs: list[str] = []
    current: dict[str, str] = {}  # mode -> the cache folder its last cold run filled

    def case(name, mode, cold):
        def call():
            if cold:
                current[mode] = tempfile.mkdtemp(prefix="ehss-numba-cache-")
                dirs.append(current[mode])
            r = _spawn(mode, current.get(mode))
            results.setdefault(name, []).append(r)
            return r["wall_s"]
        return call

    modes = ("sim", "env") if env_ok else ("sim",)
    cases = {}
    for mode in modes:
        for cold in ((False,) if quick else (True, False)):
            name = f"{mode}, {'cold' if cold else 'warm'} cache"
            cases[name] = case(name, mode, cold)
    log(f"compile: {', '.join(cases)} in fresh subprocesses, {reps} repeat(s)")
    try:
        times = interleave(cases, reps)
    finally:
        for d in dirs:
            shutil.rmtree(d, ignore_errors=True)
    return results, times


def _spawn(mode: str, cache_dir: str | None) -> dict:
    """One compile child; ``cache_dir`` None leaves numba's cache where the package keeps it."""
    env = dict(os.environ)
    if cache_dir is not None:
        env["NUMBA_CACHE_DIR"] = cache_dir
    return run_child("compile_child", [mode], env=env, timeout=1800)


def _median_of(rs: list[dict], key: str):
    """Median of ``key`` over the runs that report it; '' if none does."""
    vals = [r[key] for r in rs if key in r]
    return median(vals) if vals else ""


def compile_table(results: dict[str, list[dict]], times: dict[str, list[float]]) -> Table:
    """One row per case: subprocess wall time and the child's own timings (medians)."""
    tb = Table("compile_time", columns=["case", "repeats", "subprocess_wall_s", "min..max_s", "import_s",
                                        "first_call_s", "second_call_s", "first_batch_call_s", "make+reset+step_s"])
    for name, rs in results.items():
        mrs = ""
        if "make_s" in rs[0]:
            mrs = median([r["make_s"] + r["reset_s"] + r["step_s"] for r in rs])
        first = _median_of(rs, "simulate_first_s") if "simulate_first_s" in rs[0] else _median_of(rs, "step_s")
        second = (_median_of(rs, "simulate_second_s") if "simulate_second_s" in rs[0]
                  else _median_of(rs, "second_step_s"))
        tb.add(name, len(rs), median(times[name]), spread(times[name]), _median_of(rs, "import_s"), first, second,
               _median_of(rs, "simulate_batch_first_s"), mrs)
    return tb


def jit_cost(results: dict[str, list[dict]]) -> dict | None:
    """First simulate + simulate_batch [s] with an empty and with a warm cache; None without cold runs."""
    if "sim, cold cache" not in results:
        return None
    cold, warm = (median([r["simulate_first_s"] + r["simulate_batch_first_s"] for r in results[f"sim, {c} cache"]])
                  for c in ("cold", "warm"))
    return {"cold": cold, "warm": warm, "ratio": cold / warm}


def warm_miss(results: dict[str, list[dict]], warm_env: float | None) -> dict | None:
    """The warm env start-up [s] broken into interpreter start + exit and the child's steps, when it misses its
    target; else None."""
    if warm_env is None or not warm_env > TARGET_WARM_S:
        return None
    r = results["env, warm cache"]
    parts = {k[:-2]: median([x[k] for x in r]) for k in ("import_s", "make_s", "reset_s", "step_s")}
    return {"interpreter": warm_env - median([x["in_process_s"] for x in r]), "parts": parts}


def import_profile(top: int = 10) -> list[tuple[int, str]]:
    """(cumulative us, module) of the slowest imports under ``import ehss_gym``, from ``python -X importtime``."""
    p = subprocess.run([sys.executable, "-X", "importtime", "-c", "import ehss_gym"], cwd=repo_root(),
                       capture_output=True, text=True, timeout=300)
    rows = []
    for line in p.stderr.splitlines():
        if not line.startswith("import time:") or "[us]" in line:
            continue
        try:
            _, cum, name = (x.strip() for x in line.split(":", 1)[1].split("|"))
            rows.append((int(cum), name))
        except ValueError:
            continue
    return sorted(rows, reverse=True)[:top]
