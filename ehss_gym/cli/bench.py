"""``ehss bench``: run the performance benchmarks (``benchmarks/`` of a source checkout) and write PERF.md.

The benchmarks compare ehss-gym with the tools a user would otherwise pick, so they
need the source tree's ``benchmarks`` package, which is not part of the installed
wheel. From an installed package without the source tree the command exits with
code 2 and says so.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from ehss_gym.infra.util import report_folder

SHIPPED = os.path.join("reports", "perf")


def _benchmarks_module():
    """The ``benchmarks.__main__`` module of the source checkout holding this package, or None."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    if not os.path.isfile(os.path.join(root, "benchmarks", "__main__.py")):
        return None
    if root not in sys.path:
        sys.path.insert(0, root)
    return importlib.import_module("benchmarks.__main__")


def cmd_bench(args) -> int:
    mod = _benchmarks_module()
    if mod is None:
        print("ehss bench: error: the benchmarks/ folder is not installed with the package; run this command from "
              "a source checkout of ehss-gym (pip install -e .), or `python -m benchmarks` in its root",
              file=sys.stderr)
        return 2
    argv = ["--out", report_folder(args.out, args.quick, SHIPPED)] + (["--quick"] if args.quick else [])
    argv += ["--only", ",".join(args.only)] if args.only else []
    # the benchmark children run `python -m benchmarks...` from the checkout root
    return mod.run(mod.build_parser().parse_args(argv), "ehss bench " + " ".join(argv))


def register(sub):
    p = sub.add_parser("bench", help="run the performance benchmarks (source checkout) and write PERF.md + CSV")
    p.add_argument("--quick", action="store_true",
                   help="shrunken problems (CI, well under a minute); checks the benchmarks run, asserts no speed")
    p.add_argument("--out", default=None, help="output folder for PERF.md and the CSV files (default reports/perf; "
                                               "with --quick runs/quick/perf, so a quick run never overwrites the "
                                               "shipped one)")
    p.add_argument("--only", default=None, type=_only, help="comma-separated subset of sim,env,train,memory,compile")
    p.set_defaults(func=cmd_bench)


def _only(text: str) -> list[str]:
    known = ("sim", "env", "train", "memory", "compile")
    names = [s.strip() for s in text.split(",") if s.strip()]
    if not names or any(n not in known for n in names):
        raise argparse.ArgumentTypeError(f"--only must be a comma-separated subset of {','.join(known)}, got {text!r}")
    return names
