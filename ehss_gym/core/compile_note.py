"""A note on stderr while numba compiles the package's kernels on a cold cache, so a first run does not look hung.

The first run after installing (or after an upgrade, whose new sources invalidate numba's cache) compiles the
kernels for tens of CPU-seconds before anything else happens. numba broadcasts a ``numba:compile`` event around
every compilation it actually does, and only then: a kernel found in the cache is loaded without one (numba's
``Dispatcher.compile``). :class:`CompileNote` listens to these events for the package's cached kernels, so it is the
one place that notices a cold cache, whichever caller (``gym.make``, ``simulate``, an ``ehss`` command, a worker
process) met it first, at no cost on a warm cache. It writes one line when compiling starts and one when it is over
(no compilation for :data:`QUIET_SECONDS`) with the CPU time it took.

The note goes to stderr, never stdout, through ``tqdm.write`` so that a progress bar on stderr is redrawn below it.
Not a ``warnings`` warning: nothing is wrong, and a test run with warnings as errors would fail on a cold cache; not
``logging`` either: a library's log records are silent unless the application configures logging, and the point is
that the user sees it. ``EHSS_GYM_NO_COMPILE_NOTE=1`` (:data:`~ehss_gym.infra.NO_COMPILE_NOTE_ENV`; the commands'
``--no-progress`` sets it) hides it.
"""

from __future__ import annotations

import atexit
import os
import sys
import threading
import time

import numba
from numba.core import event
from tqdm import tqdm

from ehss_gym.infra import NO_COMPILE_NOTE_ENV

PACKAGE = __name__.split(".")[0]
PACKAGE_DIR = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# A compilation of the package's kernels comes as several top-level ones (gym.make, reset and the first step each
# compile their own), a few milliseconds of Python apart: the note ends once none followed for this long [s].
QUIET_SECONDS = 2.0
# CPU time of a cold compile, as measured (README, "How long it takes"): the env's kernels (a first env step, a small
# evaluation), and every kernel the commands use (the env's, the simulator's and the step bound's: ehss warmup) [CPU-s]
TYPICAL_CPU_S = (25, 50)


def cache_folder(path: str | None) -> str:
    """Where numba keeps the compiled kernels, for the note: ``NUMBA_CACHE_DIR`` when set, the ``__pycache__``
    folders beside the package's sources when ``path`` (a kernel's cache folder) is one of them, else ``path``."""
    if numba.config.CACHE_DIR:
        return numba.config.CACHE_DIR
    if path and os.path.commonpath([os.path.abspath(path), PACKAGE_DIR]) == PACKAGE_DIR:
        return os.path.join(PACKAGE_DIR, "*", "__pycache__")
    return path or "numba's cache"


def ours(dispatcher) -> bool:
    """A kernel of this package that numba caches on disk (an uncached one compiles in every process anyway)."""
    module = getattr(dispatcher.py_func, "__module__", None) or ""
    return module.split(".")[0] == PACKAGE and dispatcher.stats.cache_path is not None


def say(text: str) -> None:
    """``text`` as one line on stderr, above any progress bar of this process; a stderr that is gone (closed, or
    none at all) gets nothing: a note never stops a run."""
    if sys.stderr is not None:
        try:
            tqdm.write(f"{PACKAGE.replace('_', '-')}: {text}", file=sys.stderr)
        except (OSError, ValueError):
            pass


class CompileNote(event.Listener):
    """Listens to numba's ``numba:compile`` events; a note on stderr when the package's kernels compile.

    Compilations nest (a kernel's callees compile while it is typed): one counts from the first of the package's
    kernels to start until its outermost compilation ends; the note's second line waits until none started for
    :data:`QUIET_SECONDS`, or the process exits.
    """

    def __init__(self, quiet_seconds: float = QUIET_SECONDS):
        self.quiet_seconds = quiet_seconds
        self.lock = threading.RLock()
        self.depth = 0  # nesting of the compilations under way
        self.opened_at: int | None = None  # the depth at which the counted compilation started; None: none under way
        self.cpu = 0.0  # CPU time of the note's compilations so far [s]
        self.cpu_at_start = 0.0  # process CPU time when the counted compilation started [s]
        self.wall = (0.0, 0.0)  # wall clock at the note's first line and at the end of its last compilation [s]
        self.notes = 0  # notes written by this process
        self.pid = os.getpid()  # the process that wrote the first line (a forked child inherits a pending second)
        self.timer: threading.Timer | None = None  # the note's second line, pending
        self.installed = False  # listening (install)

    def on_start(self, ev) -> None:
        with self.lock:
            if self.opened_at is None and ours(ev.data["dispatcher"]) and not os.environ.get(NO_COMPILE_NOTE_ENV):
                self.opened_at = self.depth
                if self.timer is not None:  # compiling again within QUIET_SECONDS: the same note goes on
                    self.timer.cancel()
                    self.timer = None
                else:
                    self.open(ev.data["dispatcher"])
                self.cpu_at_start = time.process_time()
            self.depth += 1

    def on_end(self, ev) -> None:
        with self.lock:
            self.depth -= 1
            if self.opened_at is not None and self.depth == self.opened_at:
                self.opened_at = None
                self.cpu += time.process_time() - self.cpu_at_start
                self.wall = (self.wall[0], time.perf_counter())
                self.timer = threading.Timer(self.quiet_seconds, self.close)
                self.timer.daemon = True  # the process exits without waiting for it; atexit writes the line
                self.timer.start()

    def open(self, dispatcher) -> None:
        """The note's first line."""
        self.cpu = 0.0
        self.wall = (time.perf_counter(), 0.0)
        self.pid = os.getpid()
        where = cache_folder(dispatcher.stats.cache_path)
        if self.notes:
            say(f"compiling more of the simulator's kernels (cached in {where} afterwards)")
        else:
            low, high = TYPICAL_CPU_S
            say(f"compiling the simulator's kernels once (first run after install or after an upgrade; about {low} to "
                f"{high} CPU-seconds, cached in {where} afterwards)")
        self.notes += 1

    def close(self) -> None:
        """The note's second line, with the compilations' CPU time (this process's, all threads) and the wall time
        from the first line to the end of the last compilation [s]; nothing when no note waits for it."""
        with self.lock:
            if self.timer is None or self.opened_at is not None or self.pid != os.getpid():
                return
            self.timer.cancel()
            self.timer = None
            cpu, wall = f"{self.cpu:.{0 if self.cpu >= 10 else 1}f}", self.wall[1] - self.wall[0]
            say(f"kernels compiled in {cpu} CPU-seconds ({wall:.0f} s); later runs load them from the cache")


NOTE = CompileNote()


def install() -> None:
    """Listen to numba's compilations from now on (:mod:`ehss_gym.core.jit` calls it when it loads, before any
    kernel is defined); a second call does nothing."""
    if not NOTE.installed:
        NOTE.installed = True
        event.register("numba:compile", NOTE)
        atexit.register(NOTE.close)


__all__ = ["CompileNote", "NOTE", "install", "cache_folder", "QUIET_SECONDS", "TYPICAL_CPU_S"]
