"""``ehss bench``: run the performance benchmarks (``benchmarks/`` of a source checkout) and write PERF.md.

The benchmarks compare ehss-gym with the tools a user would otherwise pick, so they
need the source tree's ``benchmarks`` package, which is not part of the installed
wheel. From an installed package without the source tree the command exits with
code 2 and says so.
"""

from __future__ import annotations

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


def run(args) -> int:
    """Run the benchmarks of the source checkout; 2 (with a message) without one."""
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


__all__ = ["run"]
