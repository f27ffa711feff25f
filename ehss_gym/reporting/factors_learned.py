"""The learned policies' factor report (``ehss factors --learned``): ``LEARNED.md`` (prose in
templates/factors_learned.md.j2) and ``learned.csv``, from :func:`ehss_gym.study.factors_learned.run`."""

from __future__ import annotations

import math
import os

from ehss_gym._version import __version__
from ehss_gym.infra.fmt import fmt_cell
from ehss_gym.infra.util import atomic_write_text
from ehss_gym.study.factors_learned import MOSTLY, NEAR, SUITE_CAUSES, WINDOWS, variant_names

from .comparison import csv_text
from .render import render

REPORT = "LEARNED.md"
COLUMNS = (("suite", "task", "variant", "policy", "runs", "episodes_used", "G") + tuple(f"w_{w}" for w in WINDOWS)
           + tuple(f"share_{c}" for c in ("tracking", "disturbance", "effort", "chatter")))
WINDOW_LABELS = {"startup": "start-up (t < 0.2 s)", "tracking": "tracking window", "disturbance": "disturbance windows",
                 "current": "current (effort/chatter)"}


def _csv(res: dict) -> str:
    flat = []
    for b in res["blocks"]:
        for v, figs in b["variants"].items():
            for n, f in figs.items():
                flat.append({"suite": b["suite"], "task": b["task"], "variant": v, "policy": n,
                             "runs": res["runs"][n], "episodes_used": f["used"], "G": f["G"],
                             **{f"w_{w}": f["windows"][w] for w in WINDOWS},
                             **{f"share_{c}": f["share"].get(c, math.nan)
                                for c in ("tracking", "disturbance", "effort", "chatter")}})
    return csv_text(flat, COLUMNS)


def _g(x: float) -> str:
    return fmt_cell(x, 3, decimals=True)


def _share_text(share: dict) -> str:
    return ", ".join(f"{c} {s:.0%}" for c, s in sorted(share.items(), key=lambda kv: -abs(kv[1]))
                     if math.isfinite(s))


def _verdict_line(name: str, f: dict, v: dict) -> dict:
    """The rule's words for one learned group on one block."""
    removed = ", ".join(f"{c} {s:.0%}" for c, s in v["removed_share"].items())
    return {"policy": name, "G": _g(f["G"]), "gap": v["gap"], "explained": v["explained"],
            "mostly": [c for c in v["mostly"] if c not in v["explained"]], "widens": v["widens"],
            "removed": removed, "share": _share_text(f["share"]),
            "startup": _g(f["windows"]["startup"])}


def _block(b: dict, learned: list) -> dict:
    """The tables and verdicts of one (suite, task)."""
    names = list(b["variants"]["as is"])
    vs = variant_names(b["suite"])
    g_rows = [[n] + [_g(b["variants"][v][n]["G"]) for v in vs] for n in names]
    verdicts = [_verdict_line(n, b["variants"]["as is"][n], b["verdicts"][n]) for n in names if n in learned]
    # the window split as is, and with friction removed (does the disturbance windows' ratio follow its cause?)
    w_rows, nf = ([[n] + [_g(b["variants"][v][n]["windows"][w]) for w in WINDOWS] + [_g(b["variants"][v][n]["G"])]
                   for n in names] for v in ("as is", "no friction"))
    return {"suite": b["suite"], "task": b["task"], "episodes": b["episodes"], "variants": list(vs),
            "g_rows": g_rows, "w_rows": w_rows, "nf_rows": nf, "verdicts": verdicts}


def write_learned_report(res: dict, out: str, command: str, wall_s: float) -> str:
    """Write LEARNED.md and learned.csv under ``out``; returns LEARNED.md's path."""
    os.makedirs(out, exist_ok=True)
    atomic_write_text(os.path.join(out, "learned.csv"), _csv(res))
    blocks = [_block(b, res["learned"]) for b in res["blocks"]]
    text = render("factors_learned.md.j2", command=command, version=__version__, wall_s=wall_s, blocks=blocks,
                  runs=res["runs"], learned=res["learned"], policies=res["policies"], episodes=res["episodes"],
                  near=NEAR, mostly=MOSTLY, causes=SUITE_CAUSES, windows=[WINDOW_LABELS[w] for w in WINDOWS])
    path = os.path.join(out, REPORT)
    atomic_write_text(path, text)
    return path


__all__ = ["REPORT", "COLUMNS", "write_learned_report"]
