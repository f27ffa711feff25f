"""The ruler's factor table (ehss factors): removing a cause moves the class that should see it."""

import math

from ehss_gym.cli import main
from ehss_gym.core.scenarios import heldout_scenarios
from ehss_gym.core.sim import simulate_batch
from ehss_gym.envs import EnvConfig
from ehss_gym.study import factors


def test_removing_friction_lowers_the_disturbance_peak():
    base = heldout_scenarios(6, EnvConfig.from_kwargs({"task": "velocity"}).template(), 1.0)
    var = factors.variants(base)
    assert all(ev[0] == 0.0 for sc in var["no friction"] for ev in sc.friction)
    assert [len(sc.friction) for sc in var["no friction"]] == [len(sc.friction) for sc in base]  # windows kept
    assert all(sc.noise_std == (0.0,) * 4 and sc.friction == b.friction for sc, b in zip(var["no noise"], base))
    assert all(sc.plant == b.model and sc.model is None for sc, b in zip(var["no mismatch"], base))
    as_is = [t.metrics() for t in simulate_batch(base)]
    without = [t.metrics() for t in simulate_batch(var["no friction"])]
    strong = [i for i, sc in enumerate(base) if sum(ev[0] for ev in sc.friction) > 0.5]
    assert len(strong) >= 3
    for i in strong:
        assert without[i]["dst_peak"] < as_is[i]["dst_peak"], i
    # the other classes see the same samples: the windows did not move
    assert [m["steps_disturbance"] for m in without] == [m["steps_disturbance"] for m in as_is]


def test_factor_table_quick(tmp_path):
    res = factors.task_factors("velocity", 4, 1.0)
    rows = {r["factor"]: r for r in res["rows"]}
    assert set(rows) == set(factors.FACTORS) and rows["as is"]["tracking_ratio"] == 1.0
    assert rows["no friction"]["disturbance_ratio"] < 1.0
    assert 0.0 <= res["startup_share"] <= 1.0
    assert {(c["factor"], c["class"]) for c in res["checks"]} == set(factors.CHECKS)
    assert all(math.isfinite(c["ratio"]) for c in res["checks"])
    out = tmp_path / "factors"
    assert main(["factors", "--quick", "--task", "velocity", "--episodes", "3", "--out", str(out)]) == 0
    text = (out / "FACTORS.md").read_text()
    assert "ehss factors" in text and "## velocity task" in text and ("check met" in text or "check NOT met" in text)
    assert (out / "factors.csv").read_text().startswith("task,factor,tracking")


def test_the_rankings_rank_on_each_task_the_policies_that_act_on_it(monkeypatch):
    """Both tasks at once (the held-out suite alone, to be quick): a scripted compensator is ranked only on the task
    it acts on (``vinv-n2`` and ``eso-n2`` velocity, ``dcomp-n2`` position), every other scripted policy on both."""
    monkeypatch.setattr(factors, "RANK_SUITES", ("heldout",))
    blocks = factors.rankings(("velocity", "position"), 2, quick=True)
    assert [(b["suite"], b["task"]) for b in blocks] == [("heldout", "velocity"), ("heldout", "position")]
    for b in blocks:
        ranked = {n for n, _ in b["orders"]["physical"]["overall"]}
        velocity = b["task"] == "velocity"
        assert ("vinv-n2" in ranked) == velocity and ("dcomp-n2" in ranked) == (not velocity)
        assert ("eso-n2" in ranked) == velocity
        assert {"clf-n2", "clf-n4", "clf-n6", "dob-n2", "pid"} <= ranked
