"""Scaling of the execution layer (``python -m benchmarks.bench_scaling [--out reports/perf/scaling]``): a benchmark,
not a timed test.

Measures, on this machine:

1. a 16-job seed sweep (each job: one seed's randomised velocity scenarios simulated, as the study's batches
   are) at 1 and 2 workers on the ``local`` backend (worker processes) and the ``ray`` backend (a local Ray
   instance of that many CPUs);
2. Ray's own overhead per task: 200 empty tasks on a warm instance (submission, scheduling, result transfer);
3. one training seed (residual PPO, a short budget) as a job, for its cost per agent step;

then fits the cost model of docs/RAY.md, ``T(W) = T0 + ceil(N / W) * (t_job + o)``, and projects a 50 seeds x 3 n x
2 tasks training sweep (300 jobs at the default 300k steps) on a 64-core cluster. Writes ``SCALING.md`` and
``scaling.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shlex
import sys
import tempfile
import time

from ehss_gym._version import __version__
from ehss_gym.core.scenarios import sample_scenario
from ehss_gym.core.sim import simulate_batch
from ehss_gym.envs import EnvConfig
from ehss_gym.infra.execution import Backend, Executor, Job, require_ray
from ehss_gym.infra.util import atomic_write_text
from ehss_gym.train.config import Config
from ehss_gym.train.jobs import seed_job

from .common import cpu_model, load_average

SWEEP_JOBS = 16
PROJECTION = {"seeds": 50, "n": 3, "tasks": 2, "cores": 64, "timesteps": 300_000}


def sweep_job(config: dict, seed: int, context) -> dict:
    """One seed of the sweep: its randomised velocity scenarios, simulated in one batch; the compute time."""
    t0 = time.perf_counter()
    tmpl = EnvConfig.from_kwargs({"task": "velocity"}).template()
    scs = [sample_scenario(seed * 100 + k, tmpl).replace(t_end=config["t_end"]) for k in range(config["per_job"])]
    rmse = [tr.metrics()["rmse"] for tr in simulate_batch(scs)]
    return {"rmse": rmse, "compute_s": time.perf_counter() - t0, "pid": os.getpid()}


def empty_job(config: dict, seed: int, context) -> int:
    """Nothing: what a task costs beyond its work."""
    return seed


def run_sweep(backend: str, workers: int, t_end: float, per_job: int) -> dict:
    """Wall time of the 16-job sweep on ``backend`` with ``workers``, from a cold executor: ``startup_s`` is Ray's
    instance (0 locally), ``sweep_s`` the map, worker processes, imports and numba's cache loads included."""
    jobs = [Job(sweep_job, {"t_end": t_end, "per_job": per_job}, s) for s in range(SWEEP_JOBS)]
    with Executor(Backend(backend, workers=workers)) as ex:
        t_start = time.perf_counter()
        if backend == "ray":
            ex.ray()
        t_ready = time.perf_counter()
        res = ex.map(jobs, in_process=False)
        t_end_ = time.perf_counter()
    compute = sum(r["compute_s"] for r in res)
    return {"backend": backend, "workers": workers, "startup_s": t_ready - t_start, "sweep_s": t_end_ - t_ready,
            "compute_s": compute, "speedup_vs_serial_compute": compute / (t_end_ - t_ready),
            "processes": len({r["pid"] for r in res}), "rmse0": res[0]["rmse"][0]}


def task_overhead(n: int = 200) -> dict:
    """Ray's cost per task: ``n`` empty tasks on a warm one-CPU instance, one at a time and all at once."""
    with Executor(Backend("ray", workers=1)) as ex:
        ex.map([Job(empty_job, {}, 0)])  # warm: the worker exists
        t0 = time.perf_counter()
        ex.map([Job(empty_job, {}, s) for s in range(n)])
        batch = (time.perf_counter() - t0) / n
        t0 = time.perf_counter()
        for s in range(20):
            ex.map([Job(empty_job, {}, s)])
        single = (time.perf_counter() - t0) / 20
    return {"tasks": n, "per_task_batched_s": batch, "per_task_round_trip_s": single}


def training_cost(budgets: tuple[int, int], backend: str) -> dict:
    """Residual-PPO seeds of two budgets as jobs (fresh workers): the cost per agent step (the slope) and the fixed
    cost of a seed (the intercept: imports, the validation set-up, exports)."""
    walls, steps = [], []
    for timesteps in budgets:
        cfg = Config(timesteps=timesteps, eval_freq=timesteps, checkpoint_freq=timesteps, seed=0, progress=False,
                     out=tempfile.mkdtemp(prefix="ehss-bench-train-"))  # fresh: a folder with a checkpoint resumes
        with Executor(Backend(backend, workers=1)) as ex:
            t0 = time.perf_counter()
            res = ex.map([seed_job(cfg)], fresh_process=True)[0]
            walls.append(time.perf_counter() - t0)
        steps.append(res["summary"]["timesteps"])
    per_step = (walls[1] - walls[0]) / (steps[1] - steps[0])
    return {"backend": backend, "timesteps": steps, "job_s": walls, "per_step_s": per_step,
            "fixed_s": walls[0] - per_step * steps[0]}


def projection(train: dict, overhead: dict, startup_s: float) -> dict:
    """The cost model's wall time for :data:`PROJECTION` (equal jobs, one per core at a time)."""
    p = PROJECTION
    jobs = p["seeds"] * p["n"] * p["tasks"]
    t_job = train["fixed_s"] + train["per_step_s"] * p["timesteps"]
    waves = math.ceil(jobs / p["cores"])
    wall = startup_s + waves * (t_job + overhead["per_task_round_trip_s"])
    return {**p, "jobs": jobs, "t_job_s": t_job, "waves": waves, "startup_s": startup_s, "wall_s": wall,
            "serial_s": jobs * t_job, "efficiency": jobs * t_job / (wall * p["cores"])}


def write(out: str, data: dict, command: str) -> str:
    """SCALING.md and scaling.json in ``out``."""
    os.makedirs(out, exist_ok=True)
    atomic_write_text(os.path.join(out, "scaling.json"), json.dumps(data, indent=1) + "\n")
    made = f"Made by `{command}` (ehss-gym {__version__}); a benchmark on a shared machine, not a test."
    ov, pr = data["overhead"], data["projection"]
    lines = ["# Scaling of the execution layer", "", made, "",
             f"Machine: {data['cpu']}, {data['cores']} usable cores, load average {data['load_before']} before and "
             f"{data['load_after']} after (the cores are shared with other jobs: wall times include waiting).", "",
             f"## {SWEEP_JOBS}-job seed sweep", "", made, "",
             f"Each job: {data['per_job']} randomised velocity scenarios of {data['t_end']:g} s simulated in one "
             "batch, one thread. From a cold executor: start-up is starting Ray's local instance (0 for local); the "
             "sweep includes starting the worker processes, their imports and numba's cache loads (a local map "
             "starts its processes each call; Ray's workers stay up for the next call).", "",
             "| backend | workers | start-up [s] | sweep [s] | sum of job compute [s] | compute / sweep | processes |",
             "|---|---|---|---|---|---|---|"]
    lines += [f"| {r['backend']} | {r['workers']} | {r['startup_s']:.2f} | {r['sweep_s']:.2f} | {r['compute_s']:.2f} | "
              f"{r['speedup_vs_serial_compute']:.2f} | {r['processes']} |" for r in data["sweep"]]
    lines += ["", "## Ray's overhead per task", "", made, "",
              f"{ov['tasks']} empty tasks on a warm one-CPU instance: {1e3 * ov['per_task_batched_s']:.2f} ms per task "
              f"submitted together, {1e3 * ov['per_task_round_trip_s']:.2f} ms for one submitted and awaited alone.",
              "", "## Projection: 50 seeds x 3 n x 2 tasks on 64 cores", "", made, "",
              f"Training seeds here, as Ray jobs: {data['train']['timesteps'][0]} and {data['train']['timesteps'][1]} "
              f"steps in {data['train']['job_s'][0]:.1f} and {data['train']['job_s'][1]:.1f} s: "
              f"{1e6 * data['train']['per_step_s']:.1f} us per agent step (one thread) plus "
              f"{data['train']['fixed_s']:.1f} s per seed (imports, validation set-up, exports).", "",
              "| jobs | steps per job | t_job [s] | waves | start-up [s] | projected wall [min] | serial [h] | "
              "efficiency |", "|---|---|---|---|---|---|---|---|",
              f"| {pr['jobs']} | {pr['timesteps']} | {pr['t_job_s']:.0f} | {pr['waves']} | {pr['startup_s']:.1f} | "
              f"{pr['wall_s'] / 60:.1f} | {pr['serial_s'] / 3600:.1f} | {pr['efficiency']:.2f} |", "",
              "Cost model (docs/RAY.md): T(W) = T0 + ceil(N / W) (t_job + o), with T0 the start-up, o the per-task "
              "overhead, one job per core; the projection assumes this machine's per-core speed.", ""]
    path = os.path.join(out, "SCALING.md")
    atomic_write_text(path, "\n".join(lines))
    return path


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.bench_scaling", description=__doc__.split("\n")[0])
    p.add_argument("--out", default=os.path.join("runs", "bench_scaling"), help="report folder")
    p.add_argument("--t-end", type=float, default=10.0, help="scenario duration of the sweep's jobs [s]")
    p.add_argument("--per-job", type=int, default=8, help="scenarios per sweep job")
    p.add_argument("--train-steps", type=int, nargs=2, default=(8192, 32768),
                   help="the two budgets of the measured training seeds")
    args = p.parse_args(argv)
    # Ray's workers cannot import this checkout's benchmarks package: its job functions travel by value
    require_ray().cloudpickle.register_pickle_by_value(sys.modules[__name__])
    command = "python -m benchmarks.bench_scaling " + " ".join(shlex.quote(a) for a in (argv or sys.argv[1:]))
    data = {"cpu": cpu_model(), "cores": len(os.sched_getaffinity(0)), "load_before": load_average(),
            "t_end": args.t_end, "per_job": args.per_job, "sweep": []}
    for backend in ("local", "ray"):
        for workers in (1, 2):
            data["sweep"].append(run_sweep(backend, workers, args.t_end, args.per_job))
            print(data["sweep"][-1], file=sys.stderr)
    data["overhead"] = task_overhead()
    data["train"] = training_cost(tuple(args.train_steps), "ray")
    ray_start = max(r["startup_s"] for r in data["sweep"] if r["backend"] == "ray")
    data["projection"] = projection(data["train"], data["overhead"], ray_start)
    data["load_after"] = load_average()
    print(f"wrote {write(args.out, data, command.strip())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
