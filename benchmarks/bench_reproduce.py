"""Wall time of the full default ``ehss reproduce`` run (target: <= 120 s on 2 cores).

Runs the real command end to end in a fresh process (imports, numba cache loading,
every simulation, figure and table) into a temporary folder that is deleted
afterwards, so it writes nothing else. Prints the wall time, the CPU time the run
used (user + system, all threads and plot workers) and the load average before
and after: on a shared machine the wall time depends on what else runs, while the
CPU time does not (much).

Usage::

    python benchmarks/bench_reproduce.py            # the full default run
    python benchmarks/bench_reproduce.py --quick    # the CI smoke run
"""

from __future__ import annotations

import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))  # run as a script
from benchmarks.common import time_command, wall_target_line  # noqa: E402

TARGET_S = 120.0


def time_reproduce(quick: bool = False) -> dict:
    """Run ``ehss reproduce`` once into a temporary folder; returns wall [s], cpu [s] and load averages."""
    return time_command("reproduce", "paper", ["--quick"] if quick else [])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="time the CI smoke run instead of the full study")
    args = p.parse_args(argv)
    res = time_reproduce(quick=args.quick)
    what = "ehss reproduce --quick" if args.quick else "ehss reproduce (full default run)"
    print(f"{what}: wall {res['wall_s']:.1f} s, CPU {res['cpu_s']:.1f} s on {os.cpu_count()} CPU(s); "
          f"1-min load average {res['load_before']:.2f} before, {res['load_after']:.2f} after")
    if not args.quick:
        print(wall_target_line(res, TARGET_S, 2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
