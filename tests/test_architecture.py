"""The layout's rules, checked on every test run (and so in CI): one-way imports, short functions, few
function-local imports, a lint-clean tree.

Each check runs the repository's own tool in a subprocess, the way a developer runs it by hand.
"""

from __future__ import annotations

import importlib.util
import pathlib
import shutil
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
# optional or heavy dependencies only, each with a reason: torch to load a policy, Ray for ehss tune, matplotlib to
# render the env, and numba, scipy and Gymnasium where the command line reads a module that would otherwise load them
MAX_LOCAL_IMPORTS = 6


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *args], cwd=ROOT, capture_output=True, text=True, timeout=300)


def test_import_layers_hold():
    """import-linter's contracts in pyproject.toml: cli > reporting > study > train > evaluation > agents|controllers
    > envs > core > infra, and nothing imports the CLI."""
    # the README's test command installs the dev extra: a missing import-linter is a broken install, not a pass
    assert importlib.util.find_spec("importlinter") is not None, "import-linter missing: pip install -e '.[dev]'"
    p = _run("tools/lint_imports.py")
    assert p.returncode == 0, p.stdout[-4000:] + p.stderr[-2000:]
    assert "2 kept, 0 broken" in p.stdout


def test_no_long_functions_outside_kernels():
    p = _run("tools/longest_functions.py", "--limit", "80")
    assert p.returncode == 0, p.stdout


def test_function_local_imports_are_few():
    p = _run("tools/local_imports.py", "--max", str(MAX_LOCAL_IMPORTS))
    assert p.returncode == 0, p.stdout


def test_the_tree_is_lint_clean():
    ruff = shutil.which("ruff")
    # the README's test command installs the dev extra: a missing ruff is a broken install, not a reason to pass
    assert ruff is not None, "ruff is not installed: pip install -e '.[dev]'"
    # --no-cache: a test writes nothing into the checkout (ruff keeps .ruff_cache there otherwise)
    p = subprocess.run([ruff, "check", "--no-cache", "."], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stdout[-4000:]
