"""Check the import-linter contracts of pyproject.toml against the package as it is shipped.

    python tools/lint_imports.py

agents/ and train/ live at the top of the repository and are mapped into the package namespace
(``[tool.setuptools.package-dir]``), so in a checkout ``ehss_gym/`` alone is not the whole package and
``lint-imports`` run there would not see ``ehss_gym.agents`` or ``ehss_gym.train``. This script builds the
package's tree as a wheel lays it out (symbolic links in a temporary folder, nothing copied) and runs
``lint-imports`` on it. Exits with lint-imports' status.
"""

from __future__ import annotations

import os
import pathlib
import subprocess
import sys
import tempfile

import tomllib

ROOT = pathlib.Path(__file__).resolve().parents[1]


def shipped_tree(dest: pathlib.Path) -> pathlib.Path:
    """Lay out ``ehss_gym`` under ``dest`` with every mapped sub-package linked in at its import path."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    mapping = config["tool"]["setuptools"].get("package-dir", {})
    pkg = dest / "ehss_gym"
    pkg.mkdir()
    for entry in (ROOT / "ehss_gym").iterdir():
        if entry.name != "__pycache__":
            (pkg / entry.name).symlink_to(entry)
    for name, folder in mapping.items():
        parts = name.split(".")
        if parts[0] != "ehss_gym" or len(parts) != 2:
            raise SystemExit(f"tools/lint_imports.py: unsupported package-dir entry {name!r}")
        (pkg / parts[1]).symlink_to(ROOT / folder)
    return dest


def main() -> int:
    with tempfile.TemporaryDirectory(prefix="ehss-lint-") as tmp:
        tree = shipped_tree(pathlib.Path(tmp))
        env = dict(os.environ, PYTHONPATH=str(tree), PYTHONDONTWRITEBYTECODE="1")
        run = "import sys; from importlinter.cli import lint_imports_command; sys.exit(lint_imports_command())"
        cmd = [sys.executable, "-c", run, str(ROOT / "pyproject.toml")]
        # lint-imports puts the working directory first on sys.path: run it in the laid-out tree, so that
        # ehss_gym resolves there and not to the checkout's partial package or an installed copy
        return subprocess.call(cmd, cwd=tree, env=env)


if __name__ == "__main__":
    sys.exit(main())
