"""``ehss fidelity``: the digital filters against the analog ones (:mod:`ehss_gym.study.fidelity`)."""

from __future__ import annotations

import argparse
import os
import sys

from ehss_gym.infra.util import atomic_write_text, report_folder
from ehss_gym.reporting.fidelity import docs_block, replace_block, write_report
from ehss_gym.study.fidelity import PROG, run_all

from .common import check_out_folder
from .options import HelpFormatter, add_fidelity


def measure_and_write(out: str = "reports/fidelity", docs: str | None = "docs/MODEL.md", quick: bool = False,
                      progress: bool = True, cmd: str = PROG) -> str:
    """Measure everything, write the report and (unless ``docs`` is None) the docs block; FIDELITY.md's path.

    Raises:
        ValueError: if ``docs`` has no marker block (checked before any work).
    """
    doc_text = None
    if docs is not None:
        with open(docs, encoding="utf-8") as f:
            doc_text = f.read()
        replace_block(doc_text, "")  # fail early on missing markers
    res = run_all(quick=quick, progress=progress)
    path = write_report(res["ol"], res["cl"], out, cmd, res["periods"], res["cl_periods"], res["t_end"],
                        res["wall_s"], quick, docs)
    if doc_text is not None:
        link = os.path.relpath(path, os.path.dirname(os.path.abspath(docs)) or ".").replace(os.sep, "/")
        atomic_write_text(docs, replace_block(doc_text, docs_block(res["ol"], res["cl"], cmd, link)))
    return path


SHIPPED = os.path.join("reports", "fidelity")
SHIPPED_DOCS = os.path.join("docs", "MODEL.md")


def _cmdline(prog: str, args) -> str:
    parts = [prog]
    if args.out is not None:
        parts += ["--out", args.out]
    if args.docs is not None:
        parts += ["--docs", args.docs]
    if args.quick:
        parts.append("--quick")
    return " ".join(parts)


def _run_args(args, prog: str) -> int:
    name = prog.split()[-1] if prog.startswith("ehss") else prog
    cmd = _cmdline(prog, args)
    args.out = report_folder(args.out, args.quick, SHIPPED)
    if args.docs is None:
        args.docs = "none" if args.quick else SHIPPED_DOCS
    if not check_out_folder(name, args.out):
        return 2
    docs = None if args.docs.lower() == "none" else args.docs
    if docs is not None:
        try:
            with open(docs, encoding="utf-8") as f:
                replace_block(f.read(), "")
        except (OSError, ValueError) as exc:
            print(f"{name}: error: --docs {docs!r}: {exc}", file=sys.stderr)
            return 2
    path = measure_and_write(args.out, docs, quick=args.quick, progress=not args.no_progress, cmd=cmd)
    print(f"wrote {path}" + (f" and the table in {docs}" if docs else ""))
    return 0


def run(args) -> int:
    """``ehss fidelity``: measure, write the report and the docs table; 2 (with a message) for a bad option."""
    return _run_args(args, "ehss fidelity")


def main(argv=None) -> int:
    """``ehss fidelity [--out DIR] [--docs FILE] [--quick] [--no-progress]``; returns the exit code."""
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0], formatter_class=HelpFormatter)
    add_fidelity(parser)
    args = parser.parse_args(argv)
    return _run_args(args, PROG)




if __name__ == "__main__":
    sys.exit(main())
