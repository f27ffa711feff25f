"""``python -m benchmarks [--quick] [--out reports/perf] [--only sim,env,...]``: run the benchmarks, write PERF.md."""

from __future__ import annotations

import argparse
import os
import sys
import time
import traceback

from ehss_gym.infra.util import report_folder

from . import bench_compile, bench_env, bench_memory, bench_sim, bench_train, report
from .common import Section, load_average, log, machine, versions

SECTIONS = ("sim", "env", "train", "memory", "compile")


def _sections(text: str) -> list[str]:
    names = [s.strip() for s in text.split(",") if s.strip()]
    bad = [s for s in names if s not in SECTIONS]
    if bad or not names:
        raise argparse.ArgumentTypeError(f"--only must be a comma-separated subset of {','.join(SECTIONS)}, "
                                         f"got {text!r}")
    return names


def build_parser(prog: str = "python -m benchmarks") -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description="Side-by-side performance benchmarks; writes PERF.md + CSV.")
    add_arguments(p)
    return p


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--quick", action="store_true",
                   help="shrunken problems (CI, well under a minute); checks the benchmarks run, asserts no speed")
    p.add_argument("--out", default=None, help="output folder for PERF.md and the CSV files (default reports/perf; "
                                               "with --quick runs/quick/perf, so a quick run never overwrites the "
                                               "shipped one)")
    p.add_argument("--only", type=_sections, default=list(SECTIONS),
                   help=f"comma-separated subset of {','.join(SECTIONS)} (default: all)")


def run(args, command: str) -> int:
    modules = {"sim": bench_sim, "env": bench_env, "train": bench_train, "memory": bench_memory,
               "compile": bench_compile}
    args.out = report_folder(args.out, args.quick, os.path.join("reports", "perf"))
    t0 = time.perf_counter()
    meta = {"command": command, "date": report.now(), "quick": args.quick, "machine": machine(),
            "versions": versions(), "load_start": load_average()}
    sections = []
    failed = []
    for name in SECTIONS:
        if name not in args.only:
            continue
        la = load_average()
        ts = time.perf_counter()
        log(f"section {name} (load average {la})")
        try:
            sec = modules[name].run(args.quick)
        except Exception:
            tb = traceback.format_exc()
            print(tb, file=sys.stderr)
            sec = Section(name, f"{name}: FAILED")
            sec.skipped = "FAILED with an exception:\n\n```\n" + tb.strip() + "\n```\n"
            failed.append(name)
        sec.seconds = time.perf_counter() - ts
        sec.load_before = la
        sec.load_after = load_average()
        sections.append(sec)
    meta["wall_s"] = time.perf_counter() - t0
    meta["load_end"] = load_average()
    paths = report.write(args.out, sections, meta)
    log(f"wrote {len(paths)} files to {args.out} in {meta['wall_s']:.0f} s")
    for s in sections:
        for t in s.targets:
            log(f"target {t.name}: {t.measured} vs {t.goal} -> {t.status} {t.shortfall}")
    if failed:
        log(f"FAILED sections: {', '.join(failed)}")
        return 1
    return 0


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    argv = sys.argv[1:] if argv is None else list(argv)
    return run(args, " ".join(["python -m benchmarks", *argv]))


if __name__ == "__main__":
    sys.exit(main())
