"""The env's defaults table in the docs, generated from the code: ``python -m ehss_gym.envs.defaults --write``.

README.md, docs/ENV.md and the docstring of :class:`ehss_gym.envs.env.EHSSTrackingEnv` each hold the table of
:func:`ehss_gym.envs.config.defaults_table` between the markers ``<!-- env-defaults:start -->`` and
``<!-- env-defaults:end -->``. ``--write`` rewrites those blocks after a default changed; ``--check`` (and the test
suite) fails while any block differs from the table the code gives. Works in a source checkout (the files are not
part of an installed package).
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

from .config import defaults_table

ROOT = Path(__file__).resolve().parents[2]
START, END = "<!-- env-defaults:start -->", "<!-- env-defaults:end -->"
# file (relative to the checkout) -> indentation of its block (the docstring's is indented with the class body)
FILES = {"README.md": "", "docs/ENV.md": "", "ehss_gym/envs/env.py": "    "}
_BLOCK = re.compile(rf"^([ \t]*){re.escape(START)}\n.*?^[ \t]*{re.escape(END)}$", re.S | re.M)


def block(indent: str = "") -> str:
    """The marked block as a file holds it, indented by ``indent``."""
    lines = [START, "", *defaults_table().splitlines(), "", END]
    return "\n".join((indent + ln) if ln else "" for ln in lines)


def committed_block(text: str) -> str:
    """The marked block of a file's text (markers included); ValueError if it has none or several."""
    found = [m.group(0) for m in _BLOCK.finditer(text)]
    if len(found) != 1:
        raise ValueError(f"expected one {START} ... {END} block, found {len(found)}")
    return found[0]


def rewrite(text: str, indent: str) -> str:
    """``text`` with its marked block replaced by today's table."""
    committed_block(text)
    return _BLOCK.sub(lambda m: block(indent), text)


def stale(root: Path | None = None) -> list[str]:
    """The files of the checkout at ``root`` (default :data:`ROOT`) whose block differs from the table the code
    gives."""
    root = ROOT if root is None else root
    out = []
    for rel, indent in FILES.items():
        text = (root / rel).read_text(encoding="utf-8")
        try:
            if committed_block(text) != block(indent):
                out.append(rel)
        except ValueError as exc:
            out.append(f"{rel} ({exc})")
    return out


def main(argv: list[str] | None = None) -> int:
    """``--check``: 1 and the stale files while a block differs; ``--write``: rewrite the blocks."""
    ap = argparse.ArgumentParser(prog="python -m ehss_gym.envs.defaults", description=__doc__.splitlines()[0])
    ap.add_argument("--write", action="store_true", help="rewrite the marked blocks (default: check them)")
    args = ap.parse_args(argv)
    if not (ROOT / "README.md").is_file():
        print(f"no source checkout at {ROOT}: the docs are not part of an installed package", file=sys.stderr)
        return 2
    if args.write:
        for rel, indent in FILES.items():
            path = ROOT / rel
            path.write_text(rewrite(path.read_text(encoding="utf-8"), indent), encoding="utf-8")
        print("rewrote the env-defaults blocks of " + ", ".join(FILES))
        return 0
    bad = stale()
    if bad:
        print("stale env-defaults blocks (run python -m ehss_gym.envs.defaults --write): " + ", ".join(bad),
              file=sys.stderr)
        return 1
    print("env-defaults blocks up to date")
    return 0


if __name__ == "__main__":
    sys.exit(main())
