"""Small shared helpers: atomic file writes and output paths."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable


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
