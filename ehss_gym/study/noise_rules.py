"""The noise study's summaries and coded rules (pure functions of records; unit-tested).

A *cell* is a set of runs (episodes) of one setting; :func:`summary` reduces it to the numbers the rules and
the maps use. The rules:

- :func:`choose_startup`: the start-up levers (the model's pressure domain, a bumpless start, the position
  task's reference shaper) with the fewest lost episodes, then the fewest levers, then the lowest median RMSE.
- :func:`choose_ls_sigma`: Lin-Sontag's sigma per task: among the sigmas that lose no episode, the lowest
  harness-style score against the Sontag law at its own sigma (0.5 quiet-RMSE ratio + 0.5 TV ratio, medians
  over episodes, averaged over the noise levels tried).
- :func:`choose_estimator_law`: per task (n = 2), the pairs that lose no episode at any noise level of the env's
  range (0 .. 1x its largest noise) and saturate on at most ``max_sat`` of the steps at 1x are admissible; of
  those, the ones whose noise-free quiet RMSE and whose friction peak at 1x are within ``track_tol`` of the best
  admissible pair's are kept; the kept pair with the lowest median control TV at 1x is chosen.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


def is_lost(r, lost_rms: float) -> bool:
    """Divergence, or an RMS error above ``lost_rms`` over some 0.1 s window after the first 0.2 s."""
    return bool(r.get("diverged", False)) or r.get("window_rms_max", 0.0) > lost_rms


def _median(vals) -> float:
    vals = [v for v in vals if v is not None and math.isfinite(v)]
    return float(np.median(vals)) if vals else math.nan


def summary(recs: Sequence, lost_rms: float) -> dict:
    """Medians over the episodes of a cell (true error, no sensor noise in it); saturation is a mean.

    Keys: rmse, rmse_quiet, rmse_r, fric (peak |e| in friction, episodes with friction only), tv (control TV
    rate [mA/s]), sat, lost (share), n_lost, n.
    """
    live = [r for r in recs if not r.get("diverged", False)]
    return {
        "rmse": _median(r.get("rmse_true") for r in live),
        "rmse_quiet": _median(r.get("rmse_quiet_true") for r in live),
        "rmse_r": _median(r.get("rmse_r") for r in live),
        "fric": _median(r.get("max_abs_e_friction_true") for r in live),
        "tv": _median(r.get("tv_u_rate") for r in live),
        "sat": float(np.mean([r.get("saturation") for r in recs])) if recs else math.nan,
        "n_lost": sum(is_lost(r, lost_rms) for r in recs),
        "lost": sum(is_lost(r, lost_rms) for r in recs) / max(len(recs), 1),
        "n": len(recs),
    }


def choose_startup(table: dict) -> str:
    """The start-up variant to adopt.

    Args:
        table: variant label -> {"levers": number of levers it adds, "n_lost": lost episodes (both tasks, all
            scenarios), "rmse": median RMSE}.
    """
    return min(table, key=lambda k: (table[k]["n_lost"], table[k]["levers"], table[k]["rmse"]))


def choose_ls_sigma(cells: dict, ref: dict) -> float:
    """Lin-Sontag's sigma.

    Args:
        cells: sigma -> list over noise levels of summaries (:func:`summary`).
        ref: the Sontag law's summaries at the same noise levels, in the same order.

    Returns:
        The admissible sigma (no lost episode) with the lowest mean score 0.5 rmse_quiet/ref + 0.5 tv/ref; if none
        is admissible, the one with the fewest lost episodes.
    """
    def score(sums):
        parts = [0.5 * s["rmse_quiet"] / max(r["rmse_quiet"], 1e-15) + 0.5 * s["tv"] / max(r["tv"], 1e-12)
                 for s, r in zip(sums, ref)]
        return float(np.mean(parts))

    ok = [sg for sg, sums in cells.items() if all(s["n_lost"] == 0 for s in sums)]
    if not ok:
        return min(cells, key=lambda sg: (sum(s["n_lost"] for s in cells[sg]), score(cells[sg])))
    return min(ok, key=lambda sg: score(cells[sg]))


def choose_estimator_law(cells: dict, env_rows: Sequence[str], row_1x: str, row_0x: str, track_tol: float,
                         max_sat: float) -> tuple:
    """The (estimator, law) pair of one task (rule in the module docstring).

    Args:
        cells: (estimator, law) -> row label -> summary (n = 2).
        env_rows: the rows of the env's noise range (0 .. 1x).
        row_1x, row_0x: the rows of the env's largest noise and of no noise.

    Returns:
        (chosen pair, admissible pairs, kept pairs); the chosen pair is None when no pair is admissible.
    """
    adm = [k for k, rows in cells.items()
           if all(rows[r]["n_lost"] == 0 for r in env_rows) and rows[row_1x]["sat"] <= max_sat]
    if not adm:
        return None, [], []
    best_q = min(cells[k][row_0x]["rmse_quiet"] for k in adm)
    best_f = min(cells[k][row_1x]["fric"] for k in adm)
    kept = [k for k in adm if cells[k][row_0x]["rmse_quiet"] <= track_tol * best_q
            and cells[k][row_1x]["fric"] <= track_tol * best_f]
    chosen = min(kept, key=lambda k: (cells[k][row_1x]["tv"], cells[k][row_0x]["rmse_quiet"]))
    return chosen, adm, kept
