"""The ``ehss`` command line. Each sub-command lives in its own module of this package with a ``register``
function; nothing outside the CLI imports it.

Bad arguments exit with code 2 and a message that names the parameter and the accepted range
(argparse's convention).
"""

from __future__ import annotations

import argparse
import sys

from ehss_gym._version import __version__

from . import bench, evaluate, factors, fidelity, noise, reproduce, simulate, train, training_report, tune

# each exposes register(subparsers)
COMMANDS = (simulate, reproduce, noise, evaluate, factors, train, training_report, tune, bench, fidelity)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="ehss", description="EHSS servo loop with Sontag/CLF controllers.")
    parser.add_argument("--version", action="version", version=f"ehss-gym {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    for mod in COMMANDS:
        mod.register(sub)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    argv = sys.argv[1:] if argv is None else list(argv)
    args = parser.parse_args(argv)
    args.argv = argv  # the command line, for the made-by lines of figures
    return int(args.func(args) or 0)
