"""How the kernels are compiled, and the dispatch of an extension point built from its table.

Every compiled function of the core is a pure ``numba.njit`` function over flat float64 arrays (:data:`jit`), the hot
per-period ones without numba's reference-counting runtime (:data:`jit_noalloc`). An extension point (a law, an
estimator, a reference family; :mod:`ehss_gym.core.registry`) is a table row naming its kernel; :func:`dispatch`
writes the if-chain that calls the kernel of a row's code (its index in the table), so adding a row needs no edit
of the code that dispatches.

numba caches each compiled function next to its source and checks it against that file only: after editing a kernel
or a table row, clear the cache (``find . -name '*.nbi' -delete -o -name '*.nbc' -delete``) so that the callers in
other files are compiled again.
"""

from __future__ import annotations

import hashlib
import inspect
import math
import sys
from collections.abc import Sequence

import numba as nb

from .compile_note import install

install()  # a note on stderr while the kernels compile on a cold cache (core/compile_note.py)

jit = nb.njit(cache=True, fastmath=False, error_model="numpy")
# The hot per-period kernels (lanes, controller, env step) are compiled without numba's reference-counting
# runtime (NRT): they never allocate, and with NRT every array view they take (z[b], work[0], events[b], ...)
# costs an atomic incref/decref pair, measured at ~40 % of an env step. Without NRT such a view is a plain
# struct; a kernel that tries to allocate fails to compile ("NRT required but not enabled") rather than
# misbehaving. ``_nrt`` is numba's (underscore) flag for this; 0.68 honours it.
jit_noalloc = nb.njit(cache=True, fastmath=False, error_model="numpy", _nrt=False)
# A table row's kernel and the dispatch over a table are inlined into their caller (numba IR), so dispatching
# through the table costs what the hand-written if-chain it replaced cost, and they run under the caller's flags.
# So are the kernels a lane stage calls once per lane (the law's errors and filter advance, the residual's apply, the
# live-row copy): a call that is not inlined passes every array as seven machine words and keeps the relative degree
# m a run-time value in the callee, whose loops then do not unroll (inlined: 9 % off the compiled control period,
# bit for bit the same arithmetic; benchmarks/lane_stages.py).
jit_inline = nb.njit(cache=True, fastmath=False, error_model="numpy", inline="always")


def dispatch(name: str, params: Sequence[str], kernels: Sequence, module: str, *, code: str = "code",
             prefix: Sequence[str] = (), local: Sequence[str] = (), otherwise: str = "math.nan", doc: str = ""):
    """A compiled ``name(*params)`` that returns ``kernels[code](...)``: an if-chain over the table's codes.

    Each kernel gets the arguments its own parameters name, from ``params`` and ``local`` (by name), so the kernels
    of one extension point may take fewer arguments than the dispatch. An unknown code returns ``otherwise``.

    Args:
        name: the dispatch function's name.
        params: its parameters, in order.
        kernels: one compiled function per table row, in table order (the code is the index); a kernel may serve
            several rows, None a row with nothing to do here (its branch returns ``otherwise``).
        module: the module the dispatch belongs to (its source file holds numba's cache of it).
        code: the parameter or local holding the code.
        prefix: statements run before the chain (e.g. ``"r = spec[1]"``).
        local: the names ``prefix`` defines, which kernels may take.
        otherwise: the expression returned for an unknown code.
        doc: the dispatch's docstring.
    """
    lines = [f"def {name}({', '.join(params)}):", f"    {doc!r}", *(f"    {stmt}" for stmt in prefix)]
    known = set(params) | set(local)
    env = {"math": math}
    for i, kernel in enumerate(kernels):
        if kernel is None:  # a row with nothing to do here
            lines.append(f"    if {code} == {i}:\n        return {otherwise}")
            continue
        fname = kernel.__name__
        if env.get(fname, kernel) is not kernel:
            raise TypeError(f"{name}: two kernels named {fname}")
        args = list(inspect.signature(kernel.py_func).parameters)
        missing = [a for a in args if a not in known]
        if missing:
            raise TypeError(f"{name}: kernel {fname} takes {missing}, which the dispatch does not pass "
                            f"(it passes {sorted(known)})")
        env[fname] = kernel
        lines.append(f"    if {code} == {i}:  # {kernel.__module__}.{fname}")
        lines.append(f"        return {fname}({', '.join(args)})")
    lines.append(f"    return {otherwise}")
    source = "\n".join(lines) + "\n"
    # compiled against the module's own file, so numba keeps the dispatch's cache beside the module's
    exec(compile(source, inspect.getfile(sys.modules[module]), "exec"), env)
    fn = env[name]
    fn.__module__ = module
    # numba names its cache file after the qualified name: one per generated source, so a changed table never
    # reads the machine code of another one
    fn.__qualname__ = f"{name}_{hashlib.sha256(source.encode()).hexdigest()[:10]}"
    fn.source = source  # what was generated, for a reader
    return jit_inline(fn)


__all__ = ["jit", "jit_noalloc", "jit_inline", "dispatch"]
