"""Print the longest Python functions of the project, compiled numba kernels excluded.

    python tools/longest_functions.py [--top 10] [--limit 80] [PATHS ...]

A function's length is its line count from ``def`` to its last line (decorators and docstring included).
Exits 1 if any function outside a compiled kernel (decorated with ``jit``, ``jit_noalloc``, ``jit_inline`` or
``*njit*``) is longer than ``--limit`` lines, so CI can enforce it.
"""

from __future__ import annotations

import argparse
import ast
import pathlib
import sys

DEFAULT_PATHS = ("ehss_gym", "agents", "train", "benchmarks", "tools")
KERNEL_DECORATORS = ("jit", "jit_noalloc", "jit_inline", "njit")


def _is_kernel(node: ast.AST) -> bool:
    for d in getattr(node, "decorator_list", []):
        target = d.func if isinstance(d, ast.Call) else d
        name = target.attr if isinstance(target, ast.Attribute) else getattr(target, "id", "")
        if name in KERNEL_DECORATORS or "njit" in name:
            return True
    return False


def functions(paths) -> list[tuple[int, str, str, bool]]:
    """(lines, file:line, qualified name, is a compiled kernel) of every function under ``paths``."""
    out = []
    for root in paths:
        for path in sorted(pathlib.Path(root).rglob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
            stack = [(tree, "")]
            while stack:
                node, prefix = stack.pop()
                for child in ast.iter_child_nodes(node):
                    if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                        start = min([d.lineno for d in child.decorator_list] + [child.lineno])
                        n = child.end_lineno - start + 1
                        out.append((n, f"{path}:{child.lineno}", prefix + child.name, _is_kernel(child)))
                        stack.append((child, prefix + child.name + "."))
                    elif isinstance(child, ast.ClassDef):
                        stack.append((child, prefix + child.name + "."))
    return sorted(out, reverse=True)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("paths", nargs="*", default=DEFAULT_PATHS)
    p.add_argument("--top", type=int, default=10)
    p.add_argument("--limit", type=int, default=80)
    args = p.parse_args(argv)
    fns = [f for f in functions([x for x in args.paths if pathlib.Path(x).exists()]) if not f[3]]
    for n, where, name, _ in fns[:args.top]:
        print(f"{n:5d}  {name}  ({where})")
    over = [f for f in fns if f[0] > args.limit]
    print(f"{len(over)} function(s) over {args.limit} lines outside compiled kernels")
    return 1 if over else 0


if __name__ == "__main__":
    sys.exit(main())
