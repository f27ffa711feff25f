"""Packages whose names load on first use (PEP 562), so importing a package costs only what is used.

``import ehss_gym`` must stay cheap: the command line imports it before it parses its arguments, and the simulator
(numba), the env (Gymnasium) and the learned agents (torch) take seconds to load. A package lists its public names and
the submodule of each; :func:`lazy_exports` gives it the module ``__getattr__`` and ``__dir__`` that import the
submodule when a name is first read.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping


def lazy_exports(package: str, exports: Mapping[str, str]) -> tuple[Callable, Callable]:
    """``(__getattr__, __dir__)`` for ``package``: ``exports`` maps each public name to its submodule (relative,
    e.g. ``".core.sim"``); a name is imported from there on first access and kept in the package's namespace."""

    def __getattr__(name: str):
        if name not in exports:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        module = importlib.import_module(exports[name], package)
        value = getattr(module, name)
        setattr(importlib.import_module(package), name, value)
        return value

    def __dir__() -> list[str]:
        return sorted(set(vars(importlib.import_module(package))) | set(exports))

    return __getattr__, __dir__


__all__ = ["lazy_exports"]
