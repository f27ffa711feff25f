"""The schedule oracle tool (tools/schedule_oracle.py): on clf-n2 itself the law as it is scores exactly 1, the
searched pairs include it, and a name that is not a scripted CLF law is refused."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest

_spec = importlib.util.spec_from_file_location(
    "schedule_oracle", Path(__file__).resolve().parents[1] / "tools" / "schedule_oracle.py")
oracle = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(oracle)


def test_on_the_reference_law_the_law_as_it_is_scores_one_and_hindsight_is_no_worse(capsys):
    oracle.main(["--policy", "clf-n2", "--episodes", "3"])
    out = capsys.readouterr().out
    g = {k: float(v) for k, v in re.findall(r"(as it is|best fixed pair|hindsight):\s+([\d.]+)", out)}
    assert g["as it is"] == 1.0
    # the pair (1, 1) is on the grid, so the best fixed pair is no worse than the law itself
    assert (1.0, 1.0) in [(s, w) for s in oracle.SIGMA_FACTORS for w in oracle.WIDTH_FACTORS]
    assert g["best fixed pair"] <= 1.0 and g["hindsight"] > 0.0


def test_a_name_that_is_not_a_scripted_law_is_refused(capsys):
    with pytest.raises(SystemExit):
        oracle.main(["--policy", "residual-ppo-velocity-n2"])
    assert "--policy must be a scripted CLF law's name" in capsys.readouterr().err


def test_a_law_of_another_n_runs_at_that_n_and_is_scored_against_clf_n2(capsys):
    """clf-n4 runs as itself (not as clf-n2: its figure against clf-n2 is not 1), on the grid's pairs, and the
    class-wise bound is reported beside the others."""
    oracle.main(["--policy", "clf-n4", "--task", "position", "--nominal", "--episodes", "3"])
    out = capsys.readouterr().out
    g = {k: float(v) for k, v in
         re.findall(r"(as it is|best fixed pair|hindsight|each class at its best):\s+([\d.]+)", out)}
    assert set(g) == {"as it is", "best fixed pair", "hindsight", "each class at its best"}
    assert g["as it is"] != 1.0
    assert g["best fixed pair"] <= g["as it is"]
    assert g["each class at its best"] <= g["best fixed pair"]


def test_the_action_grid_spans_the_schedule_actions_ranges():
    from ehss_gym.envs.actions import SCHEDULE_RANGES
    ranges = {name: (lo, hi) for name, lo, hi in SCHEDULE_RANGES}
    assert (min(oracle.ACTION_WIDTH_FACTORS), max(oracle.ACTION_WIDTH_FACTORS)) == ranges["width"]
    assert (min(oracle.ACTION_SIGMA_FACTORS), max(oracle.ACTION_SIGMA_FACTORS)) == ranges["sigma"]
    assert 1.0 in oracle.ACTION_WIDTH_FACTORS and 1.0 in oracle.ACTION_SIGMA_FACTORS
