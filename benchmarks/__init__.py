"""Side-by-side performance benchmarks of ehss-gym against the tools a user would otherwise pick.

Run everything with ``python -m benchmarks [--quick] [--out reports/perf]`` (or ``ehss bench``
from a source checkout). Each comparison times ours (A) and a peer (B) in one run,
interleaved A B A B ..., repeats it, quotes medians and reports ratios; the full run
writes ``PERF.md`` and one CSV per table under ``--out``. ``--quick`` shrinks every
problem so the suite runs in CI in well under a minute; it checks that the
benchmarks work and asserts nothing about speed.

The code computes the numbers; the report's prose (the page, each section's table captions and notes, what
the command-timing scripts print) lives in Jinja2 templates under ``benchmarks/templates``.

Modules:
    common: timing, child processes, profiles, machine description, tables and targets.
    bench_sim: closed loop vs scipy ``solve_ivp``; plant substeps per second; batch scaling.
    kernel_profile: compiled-kernel timing breakdown and instruction counts (the profile for misses).
    bench_env: environment steps/s vs Pendulum-v1 and gym-electric-motor; vector env scaling.
    bench_train: SB3 PPO steps/s on our env vs Pendulum-v1, with the env's share of the time.
    bench_memory: peak resident memory of a large batch vs the size of its data.
    bench_compile: numba JIT cost cold and warm; warm import + first env step (timed in compile_child).
    compile_child: the fresh process bench_compile times (imports only the standard library before it).
    bench_evaluate, bench_reproduce: scripts timing the full ``ehss evaluate`` / ``ehss reproduce`` runs.
    report: renders PERF.md from the templates and writes the CSV files.
"""
