"""Assemble PERF.md and the CSV files from the benchmark sections.

The prose lives in Jinja2 templates under ``benchmarks/templates`` (``perf.md.j2`` is the page, one template per
section holds its tables' captions and notes); the code here and in the sections computes the numbers. The
templates are rendered with the package's report environment (:mod:`ehss_gym.reporting.render`: undefined names
are errors, the same number filters), on this folder.
"""

from __future__ import annotations

import math
import os
import time
import traceback

from ehss_gym.infra.util import atomic_write_text
from ehss_gym.reporting.render import environment, render_in

from .common import Section, Table, Target, fmt

TEMPLATES = os.path.join(os.path.dirname(os.path.abspath(__file__)), "templates")
SHARED_LOAD = 0.3  # 1-min load average from which the page warns that other processes shared the cores
SHARED_LOAD_COMMAND = 0.5  # ... and from which a timed command's target line says the machine was shared
COMMAND_TARGETS_S = {"evaluate": 180.0, "reproduce": 120.0}  # [s] wall time of the full default `ehss <command>`
# [s] a phase of the full default run that has a target of its own (ehss evaluate's episodes, on 2 quiet cores)
COMMAND_PHASE_TARGETS_S = {"evaluate": ("episodes", 60.0)}
COMMAND_TARGET_CORES = 2  # ... on this many cores


def render_template(template: str, **context) -> str:
    """Render ``template`` (a file name under benchmarks/templates) with ``context``."""
    return render_in(environment(TEMPLATES), template, **context)


def target_cells(t: Target) -> list[str]:
    """The cells of a target's row in the page's targets table: target, measured, goal, status, shortfall."""
    unit = "" if t.unit == "x" else f" {t.unit}"
    meas = "-" if t.measured is None else (f"{fmt(t.measured)}x" if t.unit == "x" else fmt(t.measured) + unit)
    goal = f"{'<=' if t.lower_is_better else '>='} {fmt(t.goal)}{'x' if t.unit == 'x' else unit}"
    status = t.status + (f" ({t.note})" if t.note else "")
    return [t.name, meas, goal, status, t.shortfall]


def section_body(s: Section) -> str:
    """The markdown of a section below its wall-time line: its template, or its tables and notes as they are."""
    tables = {t.name: t for t in s.tables}
    if s.template:
        text = render_template(s.template, tables=tables, **s.context)
    else:
        text = render_template("notes.md.j2", tables=s.tables, notes=s.notes)
    return text.strip("\n")


def _body_or_failure(s: Section) -> dict:
    """The section's body for the page; if its template fails, the traceback in its place (``failed`` set), so that
    one broken template does not cost the other sections' results."""
    if s.skipped:
        return {"s": s, "skipped": s.skipped, "body": "", "failed": False}
    try:
        return {"s": s, "skipped": "", "body": section_body(s), "failed": False}
    except Exception:
        tb = traceback.format_exc().strip()
        return {"s": s, "skipped": f"FAILED rendering its template:\n\n```\n{tb}\n```\n", "body": "", "failed": True}


def render(sections: list[Section], meta: dict) -> tuple[str, list[str]]:
    """PERF.md for the sections, with the run's ``meta`` (command, date, quick, machine, versions, load, wall_s).

    Returns:
        the page, and the keys of the sections whose template failed (the page shows the traceback instead).
    """
    la0, la1 = meta["load_start"], meta["load_end"]
    busy = max(la0[0], la1[0], *(s.load_before[0] for s in sections if s.load_before))
    views = [_body_or_failure(s) for s in sections]
    page = render_template("perf.md.j2", **meta, busy=busy, shared=busy >= SHARED_LOAD,
                           targets=[target_cells(t) for s in sections for t in s.targets], sections=views)
    return page, [v["s"].key for v in views if v["failed"]]


def write(out_dir: str, sections: list[Section], meta: dict) -> list[str]:
    """Write PERF.md and one CSV per table into out_dir; returns the paths written.

    Raises RuntimeError after writing them if a section's template failed.
    """
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
    page, failed = render(sections, meta)
    atomic_write_text(p, page)
    paths.append(p)
    if failed:
        raise RuntimeError(f"the template of section(s) {', '.join(failed)} failed; {p} shows the traceback(s)")
    return paths


def command_timing(command: str, res: dict, quick: bool) -> str:
    """What a timed ``ehss <command>`` run prints: its summary and, for the full run, its wall-time target.

    Args:
        command: "evaluate" or "reproduce" (a key of :data:`COMMAND_TARGETS_S`).
        res: :func:`benchmarks.common.time_command`'s result (for evaluate with episodes, workers and phases).
        quick: whether the CI smoke run was timed (it has no target).
    """
    target_s, cores = COMMAND_TARGETS_S[command], COMMAND_TARGET_CORES
    phase, phase_s = COMMAND_PHASE_TARGETS_S.get(command, (None, math.nan))
    phase_val = res.get("phases", {}).get(phase, math.nan)
    return render_template("command_timing.txt.j2", command=command, res=res, quick=quick, target_s=target_s,
                           cores=cores, cpus=os.cpu_count(), cpu_per_core=res["cpu_s"] / cores,
                           met=res["wall_s"] <= target_s, shared=not res["load_before"] < SHARED_LOAD_COMMAND,
                           phase=phase if phase in res.get("phases", {}) else None, phase_s=phase_s,
                           phase_val=phase_val, phase_met=phase_val <= phase_s)


def now() -> str:
    return time.strftime("%Y-%m-%d %H:%M:%S %Z")
