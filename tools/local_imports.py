"""List the function-local imports of the project (imports inside a function body).

    python tools/local_imports.py [--max N] [PATHS ...]

The layering rule: imports sit at the top of a module, except for optional heavy dependencies, each with a
reason in a comment on the import line. Exits 1 if there are more than ``--max`` of them or one has no
reason.
"""

from __future__ import annotations

import argparse
import ast
import pathlib
import sys

DEFAULT_PATHS = ("ehss_gym", "agents", "train")


def local_imports(paths) -> list[tuple[str, int, str]]:
    """(file, line, imported module) of every import inside a function under ``paths``."""
    out = []
    for root in paths:
        for path in sorted(pathlib.Path(root).rglob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"))
            for fn in ast.walk(tree):
                if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    continue
                for node in ast.walk(fn):
                    if isinstance(node, ast.Import):
                        out += [(str(path), node.lineno, a.name) for a in node.names]
                    elif isinstance(node, ast.ImportFrom):
                        out.append((str(path), node.lineno, "." * node.level + (node.module or "")))
    return sorted(set(out))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("paths", nargs="*", default=DEFAULT_PATHS)
    p.add_argument("--max", type=int, default=None)
    args = p.parse_args(argv)
    found = local_imports(args.paths)
    unexplained = []
    for f, line, mod in found:
        has_reason = "#" in pathlib.Path(f).read_text(encoding="utf-8").splitlines()[line - 1]
        unexplained += [] if has_reason else [(f, line)]
        print(f"{f}:{line}: {mod}" + ("" if has_reason else "  <- no reason given on the import line"))
    print(f"{len(found)} function-local import(s), {len(unexplained)} without a reason")
    too_many = args.max is not None and len(found) > args.max
    return 1 if too_many or unexplained else 0


if __name__ == "__main__":
    sys.exit(main())
