"""Test-session settings: tests write only under pytest's tmp_path, never into the checkout or the home folder.

The session records the files of the checkout (minus git's folder, virtual environments and the caches Python,
pytest and ruff keep by design) and the entries of the home folder (its top level and ``~/.ray``, where Ray keeps
its token) when it starts, and fails when it ends if a test added or removed one: a command run without its
output folder, store or cache pointed at tmp_path shows up here, on the first run, instead of on a later one.
"""

import atexit
import os
import shutil
import subprocess
import sys
import tempfile

import pytest
from hypothesis import settings
from hypothesis.configuration import set_hypothesis_home_dir
from hypothesis.database import InMemoryExampleDatabase

from ehss_gym.infra.execution import NUMBA_CACHE_ENV, numba_cache_dir, pin_blas

# tests/reference.py is a plain helper module next to the tests
sys.path.insert(0, os.path.dirname(__file__))

pin_blas()  # as every ehss command: MKL's code path fixed before any test computes (tests/test_reproducible.py)
# one numba cache for every process of the session (xdist workers, the commands' worker processes, fresh processes,
# Ray workers, which get this folder anyway): the package's per-source-version folder on the local disk, set before
# numba loads here and inherited by every process started from here; the checkout's __pycache__ stays untouched
os.environ.setdefault(NUMBA_CACHE_ENV, numba_cache_dir())

# hypothesis keeps its examples in ./.hypothesis by default (the checkout): in memory for the session instead; its
# other files (a cache of the constants it reads from the sources) go to a temporary folder removed at exit
settings.register_profile("session-memory", database=InMemoryExampleDatabase())
settings.load_profile("session-memory")
_HYPOTHESIS_HOME = tempfile.mkdtemp(prefix="ehss-hypothesis-")
set_hypothesis_home_dir(_HYPOTHESIS_HOME)
atexit.register(shutil.rmtree, _HYPOTHESIS_HOME, True)

# matplotlib keeps its font cache and config in the home folder (~/.cache/matplotlib, ~/.config/matplotlib), which
# it creates on a machine where they do not exist yet (an empty home): a folder of the session instead, shared by every
# process started from here (the font cache is built once), removed at exit; a user's own MPLCONFIGDIR is kept
if "MPLCONFIGDIR" not in os.environ:
    os.environ["MPLCONFIGDIR"] = tempfile.mkdtemp(prefix="ehss-matplotlib-")
    atexit.register(shutil.rmtree, os.environ["MPLCONFIGDIR"], True)

# stable-baselines3 makes a folder SB3-<time> in the system's temporary folder for every learn() without a logger of
# its own (sb3's logger.configure with no folder), left behind after the test: one folder of the session instead
# (SB3_LOGDIR, which it reads first), shared by every process started from here, removed at exit
if "SB3_LOGDIR" not in os.environ:
    os.environ["SB3_LOGDIR"] = tempfile.mkdtemp(prefix="ehss-sb3-")
    atexit.register(shutil.rmtree, os.environ["SB3_LOGDIR"], True)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SKIPPED_DIRS = {".git", "__pycache__", ".pytest_cache", ".ruff_cache"}
EDITOR_FILES = (".swp", ".swo", "~")  # an editor's files, saved beside the sources while the tests run
_BEFORE = "_ehss_before"


def checkout_files(root: str = ROOT) -> set[str]:
    """Paths of the files under ``root``, minus git's folder, virtual environments, caches and editor files."""
    out = set()
    for folder, dirs, names in os.walk(root):
        dirs[:] = [d for d in dirs if d not in SKIPPED_DIRS and not d.endswith(".egg-info")
                   and not os.path.isfile(os.path.join(folder, d, "pyvenv.cfg"))]
        out.update(os.path.relpath(os.path.join(folder, n), root) for n in names
                   if not n.endswith(EDITOR_FILES) and not n.startswith(".#"))
    return out


def home_entries(home: str | None = None) -> set[str]:
    """The entries of the home folder's top level and of ``~/.ray``."""
    home = home or os.path.expanduser("~")
    out = set()
    for sub in ("", ".ray"):
        folder = os.path.join(home, sub)
        if os.path.isdir(folder):
            out.update(os.path.join(sub, n) for n in os.listdir(folder))
    return out


def _snapshot() -> dict:
    return {"checkout": checkout_files(), "home": home_entries()}


def _is_controller(config) -> bool:
    return not hasattr(config, "workerinput")  # an xdist worker has workerinput; the controller checks once


def pytest_configure(config):
    """With xdist workers: compile numba's kernels into the session's cache first (tests/warm_kernels.py, two sets
    side by side), so that the workers load them instead of each compiling them again."""
    workers = getattr(config.option, "numprocesses", None)
    if _is_controller(config) and isinstance(workers, int) and workers > 1 and not config.option.collectonly:
        script = os.path.join(os.path.dirname(__file__), "warm_kernels.py")
        procs = [subprocess.Popen([sys.executable, script, part]) for part in ("sim", "env")]
        if any(p.wait() for p in procs):
            raise pytest.UsageError("compiling numba's kernels failed (tests/warm_kernels.py)")


# Units of work (an xdist group, or one test) that start first, longest first (CPU-seconds on this machine's 2 cores:
# the Ray group ~200 with its daemons, the quick evaluate CLI ~110, the benchmarks ~60, the quick headroom, the
# interrupted sweep and the quick noise study ~40 each, the fidelity run ~35): a long unit started last would leave the
# other worker idle at the end. Only the order changes (the tests do not depend on it); xdist then hands out the
# units in this order (--no-loadscope-reorder in pyproject.toml).
LONG_FIRST = ("ray", "tests/test_evaluate.py::test_cli_quick_writes_the_report", "benchmarks",
              "tests/test_headroom.py::test_quick_headroom_report",
              "tests/test_execution.py::test_an_interrupted_sweep_restarted_recomputes_only_the_missing_jobs",
              "tests/test_noise.py::test_quick_noise_report_renders", "fidelity")


def _unit(item) -> str:
    mark = item.get_closest_marker("xdist_group")
    return (mark.args[0] if mark.args else mark.kwargs.get("name")) if mark else item.nodeid


def pytest_collection_modifyitems(config, items):
    rank = {u: i for i, u in enumerate(LONG_FIRST)}
    items.sort(key=lambda item: rank.get(_unit(item), len(rank)))  # stable: the rest keep their order


def pytest_sessionstart(session):
    if _is_controller(session.config):
        setattr(session.config, _BEFORE, _snapshot())


@pytest.hookimpl(trylast=True)
def pytest_sessionfinish(session, exitstatus):
    before = getattr(session.config, _BEFORE, None)
    if before is None or session.config.option.collectonly:
        return
    after = _snapshot()
    changes = [f"{what}: {sign} {p}" for what in ("checkout", "home")
               for sign, paths in (("+", after[what] - before[what]), ("-", before[what] - after[what]))
               for p in sorted(paths)]
    if changes:
        shown = "\n  ".join(changes[:40]) + ("\n  ..." if len(changes) > 40 else "")
        session.config.get_terminal_writer().line(
            f"\nERROR: the tests changed files outside pytest's tmp_path ({len(changes)}):\n  {shown}", red=True)
        session.exitstatus = pytest.ExitCode.TESTS_FAILED
