"""How far results move between CPU code paths: the spread the cross-machine tolerances are chosen from.

Usage::

    python tools/cpu_spread.py                       # every path, both workloads
    python tools/cpu_spread.py --paths avx2 --workloads episodes --policies clf-n2 dob-n2

Each path (``tests/cpu_paths.py``: a fresh process on this CPU, then numba's machine code, numpy's SIMD dispatch and
MKL each limited to AVX2, then all three: an AVX2 machine) runs the workloads in a child process; every result is
compared with the native child's:

- ``bode``: ``ehss simulate``'s Bode command of ``reports/bode`` (the trajectory, the estimated response at full
  precision, and the CSV as printed);
- ``episodes``: a quick evaluation (``EvalConfig.quick``; every suite unless ``--suites``), per episode every metric of
  the report, and per suite, task and policy the overall figure and the class figures of the summary;
- ``bounds``: the physical bound of the step suite's cases named by ``--bounds`` (``task:amplitude``), computed afresh.

On a CPU without AVX-512 every path is the native one and the spread is 0.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tests"))

from cpu_paths import has_avx512, paths  # noqa: E402  (tests/cpu_paths.py)

BODE = ["simulate", "--reference", "chirp", "--omega-end", "300", "--t-end", "20", "--friction", "none", "--bode"]
FIGURES = ("figure", "tracking", "disturbance", "effort", "chatter")


def _bode(out: str) -> dict:
    """The Bode command's results at full precision and its CSV text."""
    import contextlib
    import io

    import numpy as np

    from ehss_gym.cli import main

    base = os.path.join(out, "chirp_velocity")
    with contextlib.redirect_stdout(io.StringIO()):
        assert main([*BODE, "--out", base]) == 0
    arrays = np.load(base + ".npz")
    from ehss_gym.core.response import frequency_response

    fr = frequency_response(arrays["t"], arrays["r"], arrays["y"])
    return {"y": arrays["y"].tolist(), "magnitude_db": fr.magnitude_db.tolist(), "phase_deg": fr.phase_deg.tolist(),
            "coherence": fr.coherence.tolist(), "csv": open(base + "_bode.csv").read()}


def _episodes(policies: list, suites: list | None) -> dict:
    """Per-episode metrics and per-block summary figures of a quick evaluation."""
    from ehss_gym import evaluation as ev
    from ehss_gym.evaluation.scoring import METRIC_KEYS

    cfg = ev.EvalConfig.quick(**({"suites": tuple(suites)} if suites else {}))
    res = ev.evaluate([ev.parse_policy(p) for p in policies], cfg, workers=1, progress=False)
    rows = {f"{r['suite']}/{r['task']}/{r['policy']}/{r['run']}/{r['episode']}":
            {k: r[k] for k in METRIC_KEYS if isinstance(r[k], (int, float))} for r in res.rows}
    summary = {f"{d['suite']}/{d['task']}/{d['policy']}": {k: d.get(k) for k in FIGURES + ("rank",)}
               for d in res.summary}
    return {"rows": rows, "summary": summary}


def _bounds(names: list) -> dict:
    """The step suite's bounds of ``task:amplitude`` cases, computed afresh [output unit * s]."""
    from ehss_gym.study.bound_table import bound_job, default_cases

    out = {}
    for name in names:
        task, amp = name.split(":")
        c = next(c for c in default_cases() if c["task"] == task and c["amplitude"] == float(amp))
        out[name] = bound_job(c, 0, None)["iae_bound"]
    return out


def child(args) -> None:
    out = {}
    if "bounds" in args.workloads:
        out["bounds"] = _bounds(args.bounds)
    if "bode" in args.workloads:
        out["bode"] = _bode(args.child)
    if "episodes" in args.workloads:
        out["episodes"] = _episodes(args.policies, args.suites)
    with open(os.path.join(args.child, "result.json"), "w") as f:
        json.dump(out, f)


def _rel(a: float, b: float) -> float:
    if a == b or (isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b)):
        return 0.0
    if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in (a, b)):
        return math.inf
    return abs(a - b) / max(abs(a), abs(b))


def _worst(pairs) -> tuple[float, str]:
    """(largest relative difference, where) over (label, a, b) triples."""
    best = (0.0, "")
    for label, a, b in pairs:
        r = _rel(a, b)
        if r > best[0]:
            best = (r, f"{label}: {a!r} vs {b!r}")
    return best


def compare(ref: dict, got: dict) -> list[str]:
    """Lines saying how far ``got`` is from ``ref``."""
    lines = []
    if "bode" in ref:
        a, b = ref["bode"], got["bode"]
        for k in ("y", "magnitude_db", "phase_deg", "coherence"):
            r, where = _worst((f"{k}[{i}]", x, y) for i, (x, y) in enumerate(zip(a[k], b[k])))
            lines.append(f"  bode {k}: max rel {r:.3g} {where}")
        diff = [(x, y) for x, y in zip(a["csv"].splitlines(), b["csv"].splitlines()) if x != y]
        lines.append(f"  bode CSV: {len(diff)} line(s) differ" + (f", e.g. {diff[0]}" if diff else ""))
    if "episodes" in ref:
        a, b = ref["episodes"], got["episodes"]
        keys = sorted({k for r in a["rows"].values() for k in r})
        moved = sum(1 for e in a["rows"] for k in a["rows"][e] if _rel(a["rows"][e][k], b["rows"][e][k]) > 0)
        total = sum(len(r) for r in a["rows"].values())
        lines.append(f"  episodes: {moved} of {total} metric cells differ")
        for k in keys:
            r, where = _worst((e, a["rows"][e].get(k), b["rows"][e].get(k)) for e in a["rows"])
            if r > 0:
                lines.append(f"    {k}: max rel {r:.3g} ({where})")
        for k in FIGURES:
            r, where = _worst((blk, a["summary"][blk][k], b["summary"][blk][k]) for blk in a["summary"])
            lines.append(f"  summary {k}: max rel {r:.3g} {where}")
        ranks = sum(a["summary"][blk]["rank"] != b["summary"][blk]["rank"] for blk in a["summary"])
        lines.append(f"  summary ranks changed: {ranks} of {len(a['summary'])}")
    if "bounds" in ref:
        for k in ref["bounds"]:
            lines.append(f"  bound {k}: rel {_rel(ref['bounds'][k], got['bounds'][k]):.3g} "
                         f"({ref['bounds'][k]!r} vs {got['bounds'][k]!r})")
    return lines


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--paths", nargs="+", default=["native", "numba-avx2", "numpy-avx2", "mkl-avx2", "torch-avx2",
                                                 "openblas-avx2", "avx2", "libm-sse2"])
    p.add_argument("--workloads", nargs="+", default=["bode", "episodes"], choices=["bode", "episodes", "bounds"])
    p.add_argument("--policies", nargs="+", default=["clf-n2", "dob-n2", "pid", "residual-ppo-position-n2"])
    p.add_argument("--suites", nargs="+", default=None)
    p.add_argument("--bounds", nargs="+", default=["velocity:0.5", "position:-0.5"])
    p.add_argument("--child", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.child:
        child(args)
        return 0
    if not has_avx512():
        print("note: this CPU has no AVX-512; every emulated path is the native one")
    tmp = tempfile.mkdtemp(prefix="ehss-cpu-spread-")
    envs = paths(tmp)
    results = {}
    for name in ["native"] + [q for q in args.paths if q != "native"]:
        folder = os.path.join(tmp, name)
        os.makedirs(folder, exist_ok=True)
        cmd = [sys.executable, __file__, "--child", folder, "--workloads", *args.workloads,
               "--policies", *args.policies, "--bounds", *args.bounds]
        cmd += ["--suites", *args.suites] if args.suites else []
        t0 = os.times()
        subprocess.run(cmd, check=True, env={**os.environ, **envs[name]}, cwd=ROOT)
        t1 = os.times()
        with open(os.path.join(folder, "result.json")) as f:
            results[name] = json.load(f)
        cpu = (t1.children_user + t1.children_system) - (t0.children_user + t0.children_system)
        print(f"{name}: {cpu:.1f} CPU-s" + ("" if name == "native" else ", against native:"), flush=True)
        if name != "native":
            print("\n".join(compare(results["native"], results[name])), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
