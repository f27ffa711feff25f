"""Assemble PERF.md and the CSV files from the benchmark sections."""

from __future__ import annotations

import os
import time

from ehss_gym.core.util import atomic_write_text

from .common import Section, Table, fmt

METHOD = """\
## Method

- Every comparison runs ours (A) and the peer (B) in this one run, interleaved A B A B ...,
  repeated; the tables quote the median and the min..max of the repeats, and ratios are
  median(peer time) / median(our time) (or rate ratios). Nothing here is a timed unit test;
  the speed targets are checked only in this report.
- First calls (numba cache load, warm-up) are made before any timing, except in section 5,
  which measures exactly that.
- Rates count plant substeps (one RK4 step of one scenario) and env steps (one `env.step`;
  for the vector env, one sub-env transition).
- Profiles explain misses: numba kernel timing breakdowns and the generated machine code for
  the compiled loop (cProfile cannot see inside it), cProfile for Python-level code.
"""


def render(sections: list[Section], meta: dict) -> str:
    lines = ["# ehss-gym performance report", ""]
    lines.append(f"Made by `{meta['command']}` on {meta['date']} in {meta['wall_s']:.0f} s of wall time"
                 f"{' (--quick: shrunken problems, for CI; not a performance result)' if meta['quick'] else ''}. "
                 "Generated; never edited by hand. CSV files beside this one hold every table.")
    lines += ["", "## Machine", ""]
    for k, v in meta["machine"].items():
        lines.append(f"- {k}: {v}")
    la0, la1 = meta["load_start"], meta["load_end"]
    lines.append(f"- load average (1, 5, 15 min): {la0} at the start, {la1} at the end; per section below")
    busy = max(la0[0], la1[0], *(s.load_before[0] for s in sections if s.load_before))
    if busy >= 0.3:
        lines.append(f"- **The cores were shared**: other processes kept the 1-minute load average up to {busy:g} "
                     f"on {meta['machine']['logical cores']} cores during this run (on the machine this report "
                     "was made on, other developers' tests and training runs), so absolute times are pessimistic "
                     "and noisy. The ratios come from interleaved runs that saw the same load; read those.")
    lines += ["", "## Package versions", ""]
    lines.append(", ".join(f"{k} {v}" for k, v in meta["versions"].items()))
    lines += ["", "## Targets", "", "| target | measured | goal | status | shortfall |",
              "| --- | --- | --- | --- | --- |"]
    for s in sections:
        for t in s.targets:
            unit = "" if t.unit == "x" else f" {t.unit}"
            meas = "-" if t.measured is None else (f"{fmt(t.measured)}x" if t.unit == "x" else fmt(t.measured) + unit)
            goal = (f"{'<=' if t.lower_is_better else '>='} {fmt(t.goal)}{'x' if t.unit == 'x' else unit}")
            status = t.status + (f" ({t.note})" if t.note else "")
            lines.append(f"| {t.name} | {meas} | {goal} | {status} | {t.shortfall} |")
    lines.append("")
    lines.append("Where a target is missed, its section says by how much and shows the profile that bounds it.")
    for s in sections:
        lines += ["", f"## {s.title}", ""]
        lines.append(f"Section wall time {s.seconds:.0f} s; load average {s.load_before} before, {s.load_after} after.")
        if s.skipped:
            lines += ["", f"**Skipped: {s.skipped}.**"]
            continue
        for t in s.tables:
            lines += ["", f"**{t.title}** (`{t.name}.csv`)", "", t.markdown()]
        if s.notes:
            lines.append("")
            for n in s.notes:
                lines.append(f"- {n}")
    lines += ["", METHOD]
    return "\n".join(lines)


def write(out_dir: str, sections: list[Section], meta: dict) -> list[str]:
    """Write PERF.md and one CSV per table into out_dir; returns the paths written."""
    os.makedirs(out_dir, exist_ok=True)
    paths = []
    tables: list[Table] = [t for s in sections for t in s.tables]
    targets = Table("targets", "Targets", ["target", "measured", "goal", "lower_is_better", "status", "note"])
    for s in sections:
        for t in s.targets:
            targets.add(t.name, t.measured if t.measured is not None else "", t.goal, t.lower_is_better, t.status,
                        t.note)
    for t in [targets, *tables]:
        p = os.path.join(out_dir, f"{t.name}.csv")
        header = f"# made by: {meta['command']} ({meta['date']})\n"
        atomic_write_text(p, header + t.csv_text())
        paths.append(p)
    p = os.path.join(out_dir, "PERF.md")
    atomic_write_text(p, render(sections, meta) + "\n")
    paths.append(p)
    return paths


def now() -> str:
    return time.strftime("%Y-%m-%d %H:%M:%S %Z")
