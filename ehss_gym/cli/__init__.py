"""The ``ehss`` command line: one row of :data:`~ehss_gym.cli.options.COMMANDS` per sub-command, nothing outside the
CLI imports it.

The options of every command are in :mod:`ehss_gym.cli.options`, which loads none of the simulator, the env or the
learned agents, so ``ehss --help`` and a bad argument answer at once; the module that runs a command (its
``run(args)``: :mod:`~ehss_gym.cli.simulate`, :mod:`~ehss_gym.cli.evaluate`, ...) is imported only when that command
runs. Bad arguments exit with code 2 and a message that names the parameter and the accepted range (argparse's
convention).
"""

from __future__ import annotations

import importlib
import os
import sys
import time

from ehss_gym._version import __version__
from ehss_gym.infra import NO_COMPILE_NOTE_ENV

from .options import COMMANDS
from .options import build_parser as _build_parser


def build_parser():
    """The ``ehss`` argument parser (every sub-command's options; nothing heavy is imported)."""
    return _build_parser(__version__)


def main(argv=None) -> int:
    """Run ``ehss`` with ``argv`` (default ``sys.argv[1:]``); returns the exit code."""
    started = time.perf_counter()
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser().parse_args(argv)
    args.started = started  # for the reports' timing lines: the command's own start-up counts too
    args.argv = argv  # the command line, for the made-by lines of figures
    quiet = getattr(args, "no_progress", False) and NO_COMPILE_NOTE_ENV not in os.environ
    if quiet:  # also hides the note while the kernels compile, here and in the worker processes started meanwhile
        os.environ[NO_COMPILE_NOTE_ENV] = "1"
    try:
        runner = importlib.import_module(f"{__name__}.{args.module}")  # the command's dependencies load here
        return int(runner.run(args) or 0)
    finally:
        if quiet:
            del os.environ[NO_COMPILE_NOTE_ENV]


__all__ = ["main", "build_parser", "COMMANDS"]
