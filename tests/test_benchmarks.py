"""The benchmark suite runs and writes its report. Nothing here asserts anything about speed."""

from __future__ import annotations

import csv
import os
import re
import subprocess
import sys

import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from benchmarks import bench_sim  # noqa: E402
from benchmarks.common import Table, Target, interleave  # noqa: E402


def test_quick_run_writes_report(tmp_path):
    out = tmp_path / "perf"
    p = subprocess.run([sys.executable, "-m", "benchmarks", "--quick", "--out", str(out)], cwd=ROOT,
                       capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-4000:]
    perf = (out / "PERF.md").read_text()
    assert f"Made by `python -m benchmarks --quick --out {out}`" in perf
    for heading in ("## Machine", "## Package versions", "## Targets", "## 1. Closed-loop", "## 2. Environment",
                    "## 3. Training", "## 4. Memory", "## 5. Compile time", "load average"):
        assert heading in perf
    assert "FAILED" not in perf
    named = set(re.findall(r"`(\w+)\.csv`", perf))
    assert {"sim_vs_solve_ivp", "substeps_per_second", "batch_scaling", "sim_profile", "memory",
            "compile_time", "ppo_training", "training_cost"} <= named
    for name in named | {"targets"}:
        with open(out / f"{name}.csv") as f:
            lines = f.read().splitlines()
        assert lines[0].startswith("# made by: python -m benchmarks --quick")
        rows = list(csv.reader(lines[1:]))
        assert len(rows) >= 2 and all(len(r) == len(rows[0]) for r in rows), name


def test_scipy_peer_matches_simulator():
    """The solve_ivp peer integrates the same loop: same states as ehss_gym.simulate over 20 ms."""
    from ehss_gym import Scenario, simulate

    sc = Scenario(**bench_sim.SETTING, t_end=0.02, log_interval=1e-4)
    ref = bench_sim.ScipyLoop(sc).run()
    ours = simulate(sc).x
    diff, per_state = bench_sim.max_rel_diff(ours, ref)
    assert ref.shape == ours.shape
    assert np.abs(ref[-1, 3]) > 0  # the valve actually moved
    assert diff < 1e-8, per_state


def test_interleave_alternates_cases():
    calls = []
    times = interleave({"a": lambda: calls.append("a"), "b": lambda: calls.append("b") or 0.5}, 3)
    assert calls == ["a", "b"] * 3
    assert times["b"] == [0.5] * 3 and len(times["a"]) == 3


def test_target_status_and_shortfall():
    assert Target("x", 500.0, 1000.0).status == "MISS"
    assert Target("x", 500.0, 1000.0).shortfall == "2x short"
    assert Target("x", 1500.0, 1000.0).status == "hit"
    assert Target("t", 2.5, 2.0, unit="s", lower_is_better=True).status == "MISS"
    assert Target("t", 1.5, 2.0, unit="s", lower_is_better=True).status == "hit"
    assert Target("x", None, 1.0).status == "not measured"


def test_table_rejects_wrong_row_length():
    t = Table("t", "t", ["a", "b"])
    with pytest.raises(ValueError, match="expected 2"):
        t.add(1)


def test_bench_cli_rejects_bad_only():
    from ehss_gym.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["bench", "--only", "nonsense"])
    assert exc.value.code == 2


def test_bench_cli_without_checkout(monkeypatch, capsys):
    from ehss_gym.cli import bench, main

    monkeypatch.setattr(bench, "_benchmarks_module", lambda: None)
    assert main(["bench", "--quick"]) == 2
    assert "source checkout" in capsys.readouterr().err
