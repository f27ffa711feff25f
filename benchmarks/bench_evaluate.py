"""Wall time of the full default ``ehss evaluate`` run (targets on 2 cores: <= 180 s in all, <= 60 s of episodes).

Runs the real command end to end in a fresh process (imports, worker start-up, numba
cache loading, every episode of every shipped policy on every suite, statistics, figures
and report) into a temporary folder that is deleted afterwards, so it writes nothing
else. Prints the wall time, the CPU time the run used (user + system of the command and
its worker processes) and the load average before and after: on a shared machine the wall
time depends on what else runs, while the CPU time does not (much); CPU / 2 is what the
wall time would be on 2 otherwise idle cores with perfect parallelism.

Usage::

    python benchmarks/bench_evaluate.py            # the full default run
    python benchmarks/bench_evaluate.py --quick    # the CI smoke run
"""

from __future__ import annotations

import argparse
import os
import re
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))  # run as a script
from benchmarks.common import time_command  # noqa: E402
from benchmarks.report import command_timing  # noqa: E402


def time_evaluate(quick: bool = False, workers: int | None = None) -> dict:
    """Run ``ehss evaluate`` once into a temporary folder.

    Returns:
        dict: wall_s and cpu_s [s], load_before / load_after (1-min load averages), episodes (count),
        phases (the command's own per-phase wall times [s]) and the printed summary.
    """
    res = time_command("evaluate", "comparison",
                       (["--quick"] if quick else []) + ([f"--workers={workers}"] if workers else []))
    m = re.search(r"(\d+) episodes in [\d.]+ s \((\d+) workers; ([^)]*)\)", res["stdout"])
    phases = {}
    if m:
        for part in m.group(3).split(","):
            name, val, _ = part.split()
            phases[name] = float(val)
    return {**res, "episodes": int(m.group(1)) if m else -1, "workers": int(m.group(2)) if m else -1,
            "phases": phases}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="time the CI smoke run instead of the full default run")
    p.add_argument("--workers", type=int, default=None, help="pass --workers to the command (default: its own)")
    args = p.parse_args(argv)
    res = time_evaluate(quick=args.quick, workers=args.workers)
    print(command_timing("evaluate", res, args.quick), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
