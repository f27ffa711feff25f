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
