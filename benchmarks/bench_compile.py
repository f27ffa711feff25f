"""Compile time: numba JIT cost on the first call, with an empty cache and with the cache warm.

Each measurement is a fresh Python subprocess (``python -m benchmarks.bench_compile
--child MODE``) with ``NUMBA_CACHE_DIR`` pointing at a new temporary folder: the first
process compiles everything (cold), the second loads the cached machine code (warm).
Cold and warm alternate, one fresh folder per repeat.

Modes:
    sim: ``import ehss_gym``, then a first ``simulate`` (single-scenario kernel) and a
        first ``simulate_batch`` (parallel kernel), each followed by a second call.
    env: ``import ehss_gym``, ``gym.make("EHSSTracking-v0")``, ``reset``, one ``step``:
        the "warm-cache import plus first step" of the targets. The subprocess's whole wall
        time (interpreter start included) is what the target is checked against.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time

from .common import Section, Table, Target, interleave, log, median, repo_root, spread

TARGET_WARM_S = 2.0
ENV_ID = "EHSSTracking-v0"  # bench_env.ENV_ID; not imported in the child, whose start-up is being timed


def child(mode: str) -> dict:
    t0 = time.perf_counter()
    import ehss_gym

    t_import = time.perf_counter() - t0
    out = {"import_s": t_import}
    if mode == "sim":
        sc = ehss_gym.Scenario(sigma=1e5, smoothing=1e3, current_limit=10.0, t_end=0.01)
        for key, fn in (("simulate", lambda: ehss_gym.simulate(sc)),
                        ("simulate_batch", lambda: ehss_gym.simulate_batch([sc, sc.replace(n=4)]))):
            t = time.perf_counter()
            fn()
            out[f"{key}_first_s"] = time.perf_counter() - t
            t = time.perf_counter()
            fn()
            out[f"{key}_second_s"] = time.perf_counter() - t
    else:
        import gymnasium as gym

        t = time.perf_counter()
        env = gym.make(ENV_ID)
        out["make_s"] = time.perf_counter() - t
        t = time.perf_counter()
        env.reset(seed=0)
        out["reset_s"] = time.perf_counter() - t
        t = time.perf_counter()
        env.step(env.action_space.sample())
        out["step_s"] = time.perf_counter() - t
        t = time.perf_counter()
        env.step(env.action_space.sample())
        out["second_step_s"] = time.perf_counter() - t
    out["in_process_s"] = time.perf_counter() - t0
    return out


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


def spawn(mode: str, cache_dir: str | None) -> dict:
    """Run a child; returns its timings plus ``wall_s``, the whole subprocess wall time."""
    env = dict(os.environ)
    if cache_dir is not None:
        env["NUMBA_CACHE_DIR"] = cache_dir
    cmd = [sys.executable, "-m", "benchmarks.bench_compile", "--child", mode]
    t0 = time.perf_counter()
    p = subprocess.run(cmd, cwd=repo_root(), env=env, capture_output=True, text=True, timeout=1800)
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        raise RuntimeError(f"compile child ({mode}) failed ({p.returncode}): {p.stderr[-2000:]}")
    r = json.loads(p.stdout.strip().splitlines()[-1])
    r["wall_s"] = wall
    return r


def run(quick: bool) -> Section:
    from . import bench_env

    sec = Section("compile", "5. Compile time: numba JIT cold vs warm cache")
    env_ok = not bench_env.env_status()
    reps = 1 if quick else 2
    results: dict[str, list[dict]] = {}
    dirs: list[str] = []
    current: dict[str, str] = {}  # mode -> the cache folder its last cold run filled

    def case(name, mode, cold):
        def call():
            if cold:
                current[mode] = tempfile.mkdtemp(prefix="ehss-numba-cache-")
                dirs.append(current[mode])
            # --quick has no cold runs: the warm runs use the package's own (default) cache
            r = spawn(mode, current.get(mode))
            results.setdefault(name, []).append(r)
            return r["wall_s"]
        return call

    cases = {}
    if not quick:
        cases["sim, cold cache"] = case("sim, cold cache", "sim", True)
    cases["sim, warm cache"] = case("sim, warm cache", "sim", False)
    if env_ok:
        if not quick:
            cases["env, cold cache"] = case("env, cold cache", "env", True)
        cases["env, warm cache"] = case("env, warm cache", "env", False)
    else:
        sec.note(f"Env start-up: skipped, {bench_env.env_status()}.")
    if quick:
        sec.note("--quick: warm cache only (the package's own cache, already filled by the other benchmarks); "
                 "the cold compile (~tens of seconds) runs in the full benchmark.")
    log(f"compile: {', '.join(cases)} in fresh subprocesses, {reps} repeat(s)")
    try:
        times = interleave(cases, reps)
    finally:
        for d in dirs:
            shutil.rmtree(d, ignore_errors=True)

    tb = Table("compile_time", "Start-up cost in a fresh subprocess (median of repeats, seconds)",
               ["case", "repeats", "subprocess_wall_s", "min..max_s", "import_s", "first_call_s", "second_call_s",
                "first_batch_call_s", "make+reset+step_s"])
    for name, rs in results.items():
        def med(key, rs=rs):
            vals = [r[key] for r in rs if key in r]
            return median(vals) if vals else ""
        mrs = ""
        if "make_s" in rs[0]:
            mrs = median([r["make_s"] + r["reset_s"] + r["step_s"] for r in rs])
        first = med("simulate_first_s") if "simulate_first_s" in rs[0] else med("step_s")
        second = med("simulate_second_s") if "simulate_second_s" in rs[0] else med("second_step_s")
        tb.add(name, len(rs), median(times[name]), spread(times[name]), med("import_s"), first, second,
               med("simulate_batch_first_s"), mrs)
    sec.tables.append(tb)
    if "sim, cold cache" in results:
        cold = median([r["simulate_first_s"] + r["simulate_batch_first_s"] for r in results["sim, cold cache"]])
        warm = median([r["simulate_first_s"] + r["simulate_batch_first_s"] for r in results["sim, warm cache"]])
        sec.note(f"JIT cost of the first simulate + simulate_batch: {cold:.1f} s with an empty cache, {warm:.2f} s "
                 f"with it warm ({cold / warm:.0f}x less).")
    if env_ok:
        warm_env = median(times["env, warm cache"])
        sec.targets.append(Target("warm-cache import + gym.make + reset + first step (fresh process)", warm_env,
                                  TARGET_WARM_S, unit="s", lower_is_better=True))
        if warm_env > TARGET_WARM_S:
            r = results["env, warm cache"]
            parts = {k: median([x[k] for x in r]) for k in ("import_s", "make_s", "reset_s", "step_s")}
            interp = warm_env - median([x["in_process_s"] for x in r])
            sec.note("Warm start-up breakdown (s): interpreter start + exit "
                     f"{interp:.2f}, " + ", ".join(f"{k[:-2]} {v:.2f}" for k, v in parts.items()))

    top = import_profile()
    if top:
        sec.note("Where `import ehss_gym` spends its time (`python -X importtime`, one run, cumulative; nested "
                 "entries include their children): " + "; ".join(f"{name} {us / 1e6:.2f} s" for us, name in top))
    if not env_ok:
        sec.targets.append(Target("warm-cache import + gym.make + reset + first step (fresh process)", None,
                                  TARGET_WARM_S, unit="s", lower_is_better=True, note="env not available"))
    return sec


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description="compile-time benchmark child")
    p.add_argument("--child", choices=("sim", "env"), required=True)
    a = p.parse_args(argv)
    print(json.dumps(child(a.child)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
