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
from benchmarks.common import time_command  # noqa: E402
from benchmarks.report import command_timing  # noqa: E402


def time_reproduce(quick: bool = False) -> dict:
    """Run ``ehss reproduce`` once into a temporary folder; returns wall [s], cpu [s] and load averages."""
    return time_command("reproduce", "paper", ["--quick"] if quick else [])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="time the CI smoke run instead of the full study")
    args = p.parse_args(argv)
    res = time_reproduce(quick=args.quick)
    print(command_timing("reproduce", res, args.quick), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
