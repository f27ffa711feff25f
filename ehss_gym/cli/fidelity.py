"""``ehss fidelity``: the digital filters against the analog ones (:mod:`ehss_gym.study.fidelity`)."""

from __future__ import annotations

import argparse
import os
import sys

from ehss_gym.infra.util import atomic_write_text, report_folder
from ehss_gym.reporting.fidelity import docs_block, replace_block, write_report
from ehss_gym.study.fidelity import PROG, run_all


def run(out: str = "reports/fidelity", docs: str | None = "docs/MODEL.md", quick: bool = False,
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


def _add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default=None, help="report folder (default reports/fidelity; with --quick "
                                               "runs/quick/fidelity, so a quick run never overwrites the shipped one)")
    p.add_argument("--docs", default=None,
                   help="markdown file whose fidelity-table block gets the main table (default docs/MODEL.md, "
                        "with --quick none; 'none' leaves docs alone)")
    p.add_argument("--quick", action="store_true",
                   help="closed loop at 30 and 10 us for 2 s only (a smoke test; seconds)")
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar")


def _run_args(args, prog: str) -> int:
    name = prog.split()[-1] if prog.startswith("ehss") else prog
    cmd = _cmdline(prog, args)
    args.out = report_folder(args.out, args.quick, SHIPPED)
    if args.docs is None:
        args.docs = "none" if args.quick else SHIPPED_DOCS
    if not str(args.out).strip():
        print(f"{name}: error: --out must be a non-empty folder path", file=sys.stderr)
        return 2
    if os.path.exists(args.out) and not os.path.isdir(args.out):
        print(f"{name}: error: --out must be a folder, {args.out!r} is a file", file=sys.stderr)
        return 2
    docs = None if args.docs.lower() == "none" else args.docs
    if docs is not None:
        try:
            with open(docs, encoding="utf-8") as f:
                replace_block(f.read(), "")
        except (OSError, ValueError) as exc:
            print(f"{name}: error: --docs {docs!r}: {exc}", file=sys.stderr)
            return 2
    path = run(args.out, docs, quick=args.quick, progress=not args.no_progress, cmd=cmd)
    print(f"wrote {path}" + (f" and the table in {docs}" if docs else ""))
    return 0


def register(sub):
    """Add the ``fidelity`` sub-command to the ``ehss`` command line."""
    p = sub.add_parser("fidelity", help="measure the digital filters (zoh, foh) against the analog ones, open and "
                                        "closed loop, at h = 30, 10, 3 us; writes reports/fidelity and the "
                                        "table in docs/MODEL.md")
    _add_arguments(p)
    p.set_defaults(func=lambda a: _run_args(a, "ehss fidelity"))


def main(argv=None) -> int:
    """``ehss fidelity [--out DIR] [--docs FILE] [--quick] [--no-progress]``; returns the exit code."""
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    _add_arguments(parser)
    args = parser.parse_args(argv)
    return _run_args(args, PROG)




if __name__ == "__main__":
    sys.exit(main())
