"""The fresh process of the compile-time benchmark: ``python -m benchmarks.compile_child --child sim|env``.

Started by :mod:`benchmarks.bench_compile`, which times it. Its start-up is the measurement, so at module level
it imports only the standard library (not even :mod:`benchmarks.common`, which loads numba): ``ehss_gym`` is
imported inside :func:`child`, timed.

Modes:
    sim: ``import ehss_gym``, then a first ``simulate`` (single-scenario kernel) and a first ``simulate_batch``
        (parallel kernel), each followed by a second call.
    env: ``import ehss_gym``, ``gym.make("EHSSTracking-v0")``, ``reset``, one ``step`` and a second one.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

ENV_ID = "EHSSTracking-v0"  # bench_env.ENV_ID; not imported here: bench_env loads gymnasium before the timing


def child(mode: str) -> dict:
    """Time the start-up steps of ``mode`` [s]: ``import_s``, the first and second calls, and ``in_process_s``."""
    t0 = time.perf_counter()
    import ehss_gym  # the measurement: the package's import time, from a fresh interpreter

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
        import gymnasium as gym  # already loaded by the timed `import ehss_gym` (which registers the env)

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


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description="compile-time benchmark child")
    p.add_argument("--child", choices=("sim", "env"), required=True)
    print(json.dumps(child(p.parse_args(argv).child)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
