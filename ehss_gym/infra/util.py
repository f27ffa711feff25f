"""Small shared helpers: atomic file writes and output paths."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable

QUICK_ROOT = os.path.join("runs", "quick")  # where quick (smoke) runs write by default: never a shipped report


def report_folder(out: str | None, quick: bool, shipped: str) -> str:
    """The output folder of a report command: ``out`` if given, else ``shipped`` (full run) or, for a quick
    run, ``runs/quick/<last part of shipped>``, so a quick run never overwrites a committed report unless asked.

    Args:
        out: the ``--out`` value (None = not given).
        quick: the run is a quick (smoke) run.
        shipped: the committed report folder of a full run, e.g. ``reports/comparison``.
    """
    if out is not None:
        return out
    return os.path.join(QUICK_ROOT, os.path.basename(os.path.normpath(shipped))) if quick else shipped


def out_paths(prefix: str) -> str:
    """Strip a known extension from an output prefix and create its folder."""
    base = str(prefix)
    for ext in (".npz", ".csv", ".png"):
        if base.endswith(ext):
            base = base[: -len(ext)]
    folder = os.path.dirname(base)
    if folder:
        os.makedirs(folder, exist_ok=True)
    return base


def atomic_write(path: str, write: Callable, mode: str = "wb") -> None:
    """Write ``path`` via a temporary file in the same folder, then rename.

    An interrupted run leaves either the old file or the new one, never half of one.
    ``write`` receives the open file object.
    """
    folder = os.path.dirname(os.path.abspath(path))
    os.makedirs(folder, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=".tmp-", suffix=os.path.splitext(path)[1])
    try:
        with os.fdopen(fd, mode) as f:
            write(f)
        os.chmod(tmp, 0o644)  # mkstemp makes 0600; a report should be readable like any file
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def atomic_write_text(path: str, text: str) -> None:
    """Atomically write a text file."""
    atomic_write(path, lambda f: f.write(text), mode="w")
