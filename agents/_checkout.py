"""Refuse a second copy of a package mapped from a checkout folder.

``agents/`` and ``train/`` at the top of the repository are the packages ``ehss_gym.agents`` and
``ehss_gym.train`` (pyproject.toml maps them). From the repository root, Python would also find them as
top-level ``agents`` / ``train``: a second module object for every file, with its own ``AGENTS``, its own
classes (``isinstance`` across the two fails) and its own module state. Importing them under those names
fails instead, with this message.
"""

from __future__ import annotations


def refuse_second_copy(name: str, package: str) -> None:
    """Raise ImportError unless the package is imported as ``package``.

    Args:
        name: the importing package's ``__name__``.
        package: the name it must be imported under (``ehss_gym.agents`` or ``ehss_gym.train``).
    """
    if name != package:
        folder = package.rsplit(".", 1)[1]
        raise ImportError(f"{folder}/ of this checkout is the package {package} (mapped in pyproject.toml): import "
                          f"{package}, not {name!r} (that would load a second copy of every module in it, whose "
                          f"classes and state are not the package's); for the training script run "
                          f"'python -m ehss_gym.train.loop'")


refuse_second_copy(__package__, "ehss_gym.agents")
