"""The walk of one env step through the source: which files a reader passes through, from ``kernels.advance`` down.

``python tools/step_walk.py [--entry ehss_gym.envs.kernels:advance] [--verbose]``

The walk reads the package's source (no import): starting at the entry function it follows every call to a
function of the package, in source order, depth first, each function's body expanded once (a second call to it is
still a stop in its file, as a reader jumps there again). The files passed through form a sequence; consecutive
entries in one file are one *stop*. A *return* is a stop in a file the walk had already left. Few stops and few
returns: the step reads top to bottom.
"""

from __future__ import annotations

import argparse
import ast
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def module_files(root: str = ROOT) -> dict[str, str]:
    """Module name -> source path of every module of the package in the checkout at ``root``."""
    out = {}
    dirs = {"ehss_gym": "ehss_gym", "ehss_gym.agents": "agents", "ehss_gym.train": "train"}
    for pkg, folder in ((p, os.path.join(root, f)) for p, f in dirs.items()):
        for dirpath, dirnames, filenames in os.walk(folder):
            dirnames[:] = [d for d in dirnames if not d.startswith((".", "__"))]
            for fn in filenames:
                if not fn.endswith(".py"):
                    continue
                rel = os.path.relpath(os.path.join(dirpath, fn), folder)[:-3].replace(os.sep, ".")
                name = pkg if rel == "__init__" else f"{pkg}.{rel.removesuffix('.__init__')}"
                out[name] = os.path.join(dirpath, fn)
    return out


class Module:
    """One parsed module: its top-level functions and the names it imports."""

    def __init__(self, name: str, path: str):
        self.name = name
        self.path = path
        with open(path, encoding="utf-8") as f:
            tree = ast.parse(f.read())
        self.functions = {n.name: n for n in tree.body if isinstance(n, ast.FunctionDef)}
        # dispatches generated from a table (``name = dispatch(...)``, ehss_gym.core.jit): a stop in this module,
        # whose branches call the table's kernels, read once like any function
        for n in tree.body:
            if isinstance(n, ast.Assign) and isinstance(n.value, ast.Call) and isinstance(n.value.func, ast.Name) \
                    and n.value.func.id in ("dispatch", "member") and isinstance(n.targets[0], ast.Name):
                self.functions[n.targets[0].id] = ast.FunctionDef(name=n.targets[0].id, args=None, body=[],
                                                                  decorator_list=[], lineno=n.lineno)
        self.classes = {n.name: n for n in tree.body if isinstance(n, ast.ClassDef)}
        self.imports: dict[str, tuple[str, str | None]] = {}  # local name -> (module, attribute or None)
        pkg = name if path.endswith("__init__.py") else name.rpartition(".")[0]
        for node in tree.body:
            if isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    parts = pkg.split(".")
                    parts = parts[:len(parts) - node.level + 1]
                    base = ".".join(parts + ([node.module] if node.module else []))
                for a in node.names:
                    self.imports[a.asname or a.name] = (base, a.name)
            elif isinstance(node, ast.Import):
                for a in node.names:
                    self.imports[a.asname or a.name.split(".")[0]] = (a.name, None)


class Walker:
    def __init__(self, root: str = ROOT, verbose: bool = False, returns: bool = True):
        self.root = root
        self.files = module_files(root)
        self.modules: dict[str, Module] = {}
        self.expanded: set[tuple[str, str]] = set()
        self.trail: list[str] = []  # files passed through, in order
        self.verbose = verbose
        self.returns = returns  # the way back to the caller is a move too

    def module(self, name: str) -> Module | None:
        if name not in self.files:
            return None
        if name not in self.modules:
            self.modules[name] = Module(name, self.files[name])
        return self.modules[name]

    def resolve(self, mod: Module, call: ast.Call) -> tuple[Module, ast.FunctionDef] | None:
        """The package function a call names (``f(...)``, ``module.f(...)``, ``obj.method(...)`` of a class in the
        same module is not followed), or None."""
        f = call.func
        if isinstance(f, ast.Name):
            if f.id in mod.functions:
                return mod, mod.functions[f.id]
            if f.id in mod.imports:
                base, attr = mod.imports[f.id]
                return self._lookup(base, attr)
        elif isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name) and f.value.id in mod.imports:
            base, attr = mod.imports[f.value.id]
            target = base if attr is None else f"{base}.{attr}"
            return self._lookup(target, f.attr)
        return None

    def _lookup(self, modname: str, attr: str | None, depth: int = 0) -> tuple[Module, ast.FunctionDef] | None:
        m = self.module(modname)
        if m is None or attr is None or depth > 5:
            return None
        if attr in m.functions:
            return m, m.functions[attr]
        if attr in m.imports:  # re-exported
            base, a = m.imports[attr]
            return self._lookup(base, a, depth + 1)
        return None

    def visit(self, mod: Module, fn: ast.FunctionDef, depth: int = 0, caller: str | None = None) -> bool:
        """Read ``fn`` (once: a function already read is no stop); True if it was read now."""
        key = (mod.name, fn.name)
        if key in self.expanded:
            return False
        self.expanded.add(key)
        if self.returns or caller != mod.path:  # calls only: a call within the file is no move
            self.trail.append(mod.path)
        if self.verbose:
            print("  " * depth + f"{os.path.relpath(mod.path, self.root)}:{fn.name}")
        calls = [n for stmt in fn.body for n in ast.walk(stmt) if isinstance(n, ast.Call)]
        calls.sort(key=lambda n: (n.lineno, n.col_offset))
        for call in calls:
            target = self.resolve(mod, call)
            if target is None:
                continue
            if self.visit(*target, depth + 1, mod.path) and self.returns:
                self.trail.append(mod.path)  # back in the caller
        return True


def walk(entry: str, root: str = ROOT, verbose: bool = False, returns: bool = True) -> dict:
    """Stops, files and returns of the walk from ``entry`` (``module:function``) in the checkout at ``root``; without
    ``returns`` only the calls move the reader (the way back to a caller is not counted)."""
    modname, _, fname = entry.partition(":")
    w = Walker(root, verbose, returns)
    mod = w.module(modname)
    if mod is None or fname not in mod.functions:
        raise SystemExit(f"step_walk: no function {entry!r}")
    w.visit(mod, mod.functions[fname])
    stops = [f for i, f in enumerate(w.trail) if i == 0 or f != w.trail[i - 1]]
    seen: set[str] = set()
    returns = 0
    for f in stops:
        if f in seen:
            returns += 1
        seen.add(f)
    rel = [os.path.relpath(f, root) for f in stops]
    entered = {}
    for f in rel:
        entered[f] = entered.get(f, 0) + 1
    return {"stops": len(stops), "files": len(seen), "returns": returns, "sequence": rel, "entered": entered}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python tools/step_walk.py", description=__doc__.split("\n\n")[0])
    p.add_argument("--entry", default="ehss_gym.envs.kernels:advance", help="module:function to start from")
    p.add_argument("--verbose", action="store_true", help="print the call tree")
    p.add_argument("--calls-only", action="store_true",
                   help="count only the moves into a called function, not the way back to its caller")
    p.add_argument("--root", default=ROOT, help="the checkout to read (default: this one)")
    args = p.parse_args(argv)
    r = walk(args.entry, args.root, args.verbose, not args.calls_only)
    what = "calls into a file already left" if args.calls_only else "returns to a file already left"
    print(f"{r['stops']} stops in {r['files']} files, {r['returns']} {what}")
    print("  " + " -> ".join(os.path.basename(f) for f in r["sequence"]))
    for f, k in sorted(r["entered"].items(), key=lambda kv: -kv[1]):
        print(f"  {f}: entered {k} times")
    return 0


if __name__ == "__main__":
    sys.exit(main())
