"""The headroom table (ehss headroom): its per-episode search, its oracles, and the quick report's structure."""

import csv
import math

import numpy as np
import pytest

from ehss_gym.cli import main
from ehss_gym.controllers import CLFPolicy, ConstantResidualPolicy, FrictionFeedforwardPolicy
from ehss_gym.core.signals import sine
from ehss_gym.envs import EnvConfig
from ehss_gym.envs.rollouts import rollout
from ehss_gym.evaluation.scoring import CLASSES
from ehss_gym.evaluation.suites import SUITES
from ehss_gym.study import headroom as hr


def _fake(value: float, centre: float) -> dict:
    """Metrics whose every class pair grows as (1 + |value - centre|), so the objective's minimum is at ``centre``."""
    f = 1.0 + abs(value - centre)
    return {"diverged": False, "lost_track": False, "trk_rmse": f, "trk_iae": f, "dst_peak": f, "dst_iae": f,
            "tv_u_rate": f, "rms_u": f, "t_tracking": 1.0, "t_disturbance": 0.5}


def test_the_per_episode_search_finds_each_episodes_own_best_and_keeps_the_base_on_a_tie():
    # per episode a different optimum; episode 2's optimum is the base value 0 (kept), episode 3's lies between grid
    # points (reached by the refinement within its step)
    centres = [0.3, -3.0, 0.0, 0.5]
    search = hr.Search1D(grid=(0.1, -0.1, 0.3, -0.3, 1.0, -1.0, 3.0, -3.0), lo=0.01, hi=10.0, step=0.25, rounds=3)
    calls = []

    def run_values(values, idx):
        calls.append(len(idx))
        return [_fake(v, centres[i]) for v, i in zip(values, idx)]

    metrics, best = hr.search_episodes(search, 0.0, run_values, [False] * 4, "velocity")
    assert best[0] == pytest.approx(0.3) and best[1] == pytest.approx(-3.0) and best[2] == 0.0
    assert abs(best[3] - 0.5) < abs(0.3 - 0.5) and abs(best[3] - 0.5) < 0.1
    assert [m["trk_rmse"] for m in metrics] == [_fake(b, c)["trk_rmse"] for b, c in zip(best, centres)]
    assert all(n >= 1 for n in calls) and calls[0] == 4  # the base value first, for every episode


def test_a_failing_candidate_is_never_kept():
    search = hr.Search1D(grid=(1.0,), lo=0.01, hi=10.0, step=0.25, rounds=1)

    def run_values(values, idx):
        return [{**_fake(v, 1.0), "diverged": v != 0.0} for v in values]

    _, best = hr.search_episodes(search, 0.0, run_values, [True], "velocity")
    assert best == [0.0]


def test_per_lane_feedforward_equals_one_policy_per_episode_and_a_zero_bias_equals_the_base_law():
    kw = {"task": "velocity"}
    tmpl = EnvConfig.from_kwargs(kw).template()
    events = [((1.8, 0.2, 0.3),), ((0.9, 0.1, 0.35), (1.2, 0.4, 0.45))]
    scs = [tmpl.replace(reference=sine(1.0, 2.0), friction=f, t_end=1.0) for f in events]
    cfg = EnvConfig.from_kwargs(kw)
    both = rollout(FrictionFeedforwardPolicy(cfg, friction_by_lane=events), kw, scs)
    for sc, f, r in zip(scs, events, both):
        alone = rollout(FrictionFeedforwardPolicy(cfg, f), kw, [sc])[0]
        assert _same(alone.metrics, r.metrics)
    # the study runs both doublets side by side in one rollout: each block as if alone
    pair = hr.SideBySide([FrictionFeedforwardPolicy(cfg, start_at_edge=e, friction_by_lane=events) for e in (0, 1)],
                         (2, 2))
    side = rollout(pair, kw, scs * 2)
    edge = rollout(FrictionFeedforwardPolicy(cfg, start_at_edge=True, friction_by_lane=events), kw, scs)
    assert all(_same(a.metrics, b.metrics) for a, b in zip(side, both + edge))
    assert not _same(both[0].metrics, edge[0].metrics)
    zero = rollout(ConstantResidualPolicy(cfg, currents=[0.0, 0.0]), kw, scs)
    base = rollout(CLFPolicy(cfg), kw, scs)
    assert all(_same(z.metrics, b.metrics) for z, b in zip(zero, base))
    biased = rollout(ConstantResidualPolicy(cfg, currents=[0.5, -0.5]), kw, scs)
    assert biased[0].metrics["rms_u"] != base[0].metrics["rms_u"]
    with pytest.raises(ValueError, match=r"currents must be finite currents within \+-10 mA"):
        ConstantResidualPolicy(cfg, currents=[11.0])
    with pytest.raises(ValueError, match="friction_by_lane gives events for 2 envs, the batch has 1"):
        rollout(FrictionFeedforwardPolicy(cfg, friction_by_lane=events), kw, scs[:1])


def test_the_combined_oracles_start_from_their_compensation_and_never_end_above_it():
    # two unmodelled episodes of different delays: at the base width alone the search's run of each is the
    # compensated law's own run (delay known, both known), to the last bit; with a grid its pick is never worse than
    # that run by the search's own objective, and where it moved the width the metrics moved with it
    cfg = hr.HeadroomConfig.quick_config(tasks=("position",), episodes=2)
    eps = hr.suite_episodes(cfg, "position")["unmodelled"]
    assert len({ep.physical["unmodelled"].delay for ep in eps}) == 2
    kw = {"task": "position", **cfg.eval_config().env_kwargs()}
    known = hr._known("position", kw, eps, None)
    width = float(EnvConfig.from_kwargs(kw).loop.smoothing)
    only_base = hr.Search1D(grid=(width,), lo=0.1, hi=1e6, step=0.25, rounds=0)
    for run, ref in ((hr._delay_width, "delay known"), (hr._both_width, "both known")):
        ms, vals = run("position", kw, eps, only_base)
        assert vals == [width, width] and all(_same(a, b) for a, b in zip(ms, known[ref][0]))
        ms, vals = run("position", kw, eps, hr.QUICK_WIDTH)
        for m, v, k, noisy in zip(ms, vals, known[ref][0], hr._noisy(eps)):
            assert hr._objective(m, k, noisy, "position") <= 0.0
            assert _same(m, k) == (v == width)


def _same(a: dict, b: dict) -> bool:
    """Two metrics dicts equal value for value (NaN equal to NaN)."""
    return a.keys() == b.keys() and all(a[k] == b[k] or (a[k] != a[k] and b[k] != b[k]) for k in a)


def _csv(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def test_quick_headroom_report(tmp_path):
    out = tmp_path / "headroom"
    argv = ["headroom", "--quick", "--workers", "1", "--no-progress", "--out", str(out), "--store",
            str(tmp_path / "store")]
    assert main(argv) == 0
    text = (out / "HEADROOM.md").read_text()
    assert "Generated by `ehss headroom --quick" in text and (out / "headroom.png").stat().st_size > 0
    cfg = hr.HeadroomConfig.quick_config()
    rows = _csv(out / "headroom.csv")
    blocks = {(r["task"], r["suite"]) for r in rows}
    # every suite of ehss evaluate, both tasks; every variant at its agent periods in each block
    assert blocks == {(t, s) for t in cfg.tasks for s in SUITES if hr.suite_episodes(cfg, t).get(s)}
    for task, suite in blocks:
        got = {r["policy"] for r in rows if r["task"] == task and r["suite"] == suite}
        want = {hr.label(v, ap, cfg) for v in hr.VARIANTS for ap in cfg.periods_of(v, suite)
                if not v.suites or suite in v.suites}
        assert got == want, (task, suite)
        ref = next(r for r in rows if r["task"] == task and r["suite"] == suite and r["policy"] == "clf-n2")
        assert float(ref["figure"]) == 1.0 and float(ref["tracking"]) == 1.0
    for task in cfg.tasks:
        assert f"## {task} task" in text
        # friction feed-forward knowing the events helps the disturbance class of some suite with friction
        ff = [float(r["disturbance"]) for r in rows if r["task"] == task and r["variant"] == "ff centred"
              and r["disturbance"] not in ("", "nan")]
        assert ff and min(ff) < 1.0, task
    # the base law and the observer act every control period: the agent period changes nothing, to the last bit
    lines = text.splitlines()
    assert sum(1 for ln in lines if "| base law |" in ln and ln.endswith("| the same to the last bit |")) == len(blocks)
    assert sum(1 for ln in lines if "| heldout | base law | 5, 20, 200 | the same to the last bit |" in ln) == 2
    assert sum(1 for ln in lines if "| heldout | dob-n2 | 5, 20 | the same to the last bit |" in ln) == 2
    assert sum(1 for ln in lines if "| heldout | dcomp-n2 | 5, 20 | the same to the last bit |" in ln) == 2
    assert sum(1 for ln in lines if "| heldout | vinv-n2 | 5, 20 | the same to the last bit |" in ln) == 2
    assert sum(1 for ln in lines if "| heldout | eso-n2 | 5, 20 | the same to the last bit |" in ln) == 2
    # a scripted compensator on a task where its rule chose none (COMPENSATOR_ROWS) is the base law, to the last bit
    for name, task in (("dcomp-n2", "velocity"), ("vinv-n2", "position"), ("eso-n2", "position")):
        for suite in {s for t, s in blocks if t == task}:
            row = next(r for r in rows if r["task"] == task and r["suite"] == suite and r["variant"] == name)
            ref = next(r for r in rows if r["task"] == task and r["suite"] == suite and r["policy"] == "clf-n2")
            assert [row[c] for c in ("figure", *CLASSES)] == [ref[c] for c in ("figure", *CLASSES)], (name, suite)
    # the oracles knowing the unmodelled effects run on the unmodelled suite only; the ideal corrections' sizes
    known = {r["suite"] for r in rows if r["variant"] in ("delay known", "valve known", "both known",
                                                          "delay known, best width", "both known, best width")}
    assert known == {"unmodelled"}
    corr = _csv(out / "corrections.csv")
    assert {r["task"] for r in corr} == set(cfg.tasks)
    assert all(float(r["rms"]) > 0.0 and float(r["max_abs"]) >= float(r["max_rms"]) for r in corr)
    for cls in CLASSES:
        assert any(r[cls] not in ("", "nan") and math.isfinite(float(r[cls])) for r in rows), cls
    assert np.isfinite([float(r["figure_hi"]) for r in rows]).all()


def test_on_another_base_every_variant_runs_on_that_loop_and_the_base_law_is_it(tmp_path):
    """``--base eso-n2``: the base law's rows are eso-n2's loop (so eso-n2 itself scores 1 in every class, to the last
    bit), the compensators run on top of it, and the report says so; an unknown base is refused by name."""
    cfg = hr.HeadroomConfig.quick_config(tasks=("velocity",), base="eso-n2")
    assert cfg.base_settings("velocity") == {"estimator": "eso", "observer_hz": 100.0}
    kw = hr.variant_config(cfg, hr.VARIANT_BY_NAME["vinv-n2"], "velocity", "heldout", [], 5)["env_kwargs"]
    assert kw["estimator"] == "eso" and kw["inverse_threshold"] > 0.0  # the compensator on top of the base loop
    out = tmp_path / "hr"
    assert main(["headroom", "--quick", "--task", "velocity", "--base", "eso-n2", "--workers", "1", "--no-progress",
                 "--out", str(out), "--store", str(tmp_path / "store")]) == 0
    rows = _csv(out / "headroom.csv")
    for suite in {r["suite"] for r in rows}:
        row = next(r for r in rows if r["suite"] == suite and r["policy"] == "eso-n2 @5")
        assert [float(row[c]) for c in ("figure", *CLASSES) if row[c] not in ("", "nan")] == \
            [1.0] * sum(row[c] not in ("", "nan") for c in ("figure", *CLASSES)), suite
    assert "**Base**: every variant, the base law included, runs on the loop of `eso-n2`" in (
        out / "HEADROOM.md").read_text()
    # the cause split runs on the same loop and says so
    causes = tmp_path / "causes"
    assert main(["headroom", "--causes", "delay", "--quick", "--task", "velocity", "--base", "eso-n2", "--workers",
                 "1", "--no-progress", "--out", str(causes), "--store", str(tmp_path / "store")]) == 0
    text = (causes / "CAUSES.md").read_text()
    assert "**Base**: every variant, the base law included, runs on the loop of `eso-n2`" in text
    assert "| eso-n2 @5 | 1 [1, 1] | 1 |" in text
    with pytest.raises(ValueError, match="base must be clf-n2 or a scripted compensator's n = 2 name"):
        hr.HeadroomConfig(base="dob-n2")


def test_the_largest_headroom_table_shows_the_best_scripted_policy_that_passes_the_gate():
    """Beside the best oracle: the lowest figure among the scripted policies at the base period that pass the gate
    (a lower one that fails it is passed over), with its name."""
    from ehss_gym.reporting import headroom as report

    h = {"ratio": 0.8, "lo": 0.7, "hi": 0.9, "oracle": "true model", "few": False, "material": True, "has": True,
         "observes": "the plant-model mismatch", "n": 32}

    def row(policy, g, failed=False):
        return {"policy": policy, "figure": g, "figure_lo": g - 0.01, "figure_hi": g + 0.01, "failed": failed}

    block = {"task": "velocity", "suite": "unmodelled", "headroom": {"overall": h},
             "stats": [row("clf-n2", 1.0), row("dob-n2 @5", 0.9), row("vinv-n2 @5", 0.3, failed=True),
                       row("eso-n2 @5", 0.2), row("eso-n2 @20", 0.1), row("true model", 0.8)]}
    (line,) = report._largest([block], "velocity")
    assert line[0] == "overall" and line[1] == "unmodelled" and line[-1] == "0.2 [0.19, 0.21] eso-n2"
