"""Where the learned policies' figures come from (ehss factors --learned): every cause removed for every policy,
the reference law included, and the figures split by time window."""

import math
from dataclasses import replace

import numpy as np
import pytest

from ehss_gym.cli import build_parser
from ehss_gym.evaluation.harness import evaluate
from ehss_gym.evaluation.scoring import PHYSICAL_FLOORS
from ehss_gym.evaluation.specs import scripted_spec
from ehss_gym.evaluation.suites import EvalConfig, build_episodes
from ehss_gym.infra.execution import Backend, Executor
from ehss_gym.reporting.factors_learned import write_learned_report
from ehss_gym.study import factors_learned as fl

TASK = "velocity"


@pytest.fixture(scope="module")
def tiny():
    """Two 1 s episodes per suite, in this process: clf-n2, a copy of it under another name, and one seed of a
    shipped learned group."""
    groups = fl.learned_specs((TASK,))
    if not groups:
        pytest.skip("no shipped learned n = 2 group of the velocity task")
    learned = replace(groups[-1], runs=groups[-1].runs[:1])
    specs = [scripted_spec("clf-n2"), scripted_spec("clf-n2", label="copy"), learned]
    with Executor(Backend("local", workers=1), progress=False) as ex:
        res = fl.run((TASK,), 2, executor=ex, specs=specs, episode_seconds=1.0)
    return res, learned.name


def test_variant_episodes_remove_one_cause_each():
    base = build_episodes(EvalConfig(suites=fl.SUITES, tasks=(TASK,), heldout_episodes=3))
    eps = fl.variant_episodes(base)
    assert len(eps) == 3 * len(fl.variant_names("heldout")) + 3 * len(fl.variant_names("unmodelled"))
    assert len({(e.suite, e.episode_id) for e in eps}) == len(eps)
    src = {(e.suite, e.episode_id): e.physical for e in base}
    for e in eps:
        orig, v = src[(e.suite, e.episode_id.split(fl.SEP)[0])], fl.variant_of(e.episode_id)
        p, um, um0 = e.physical, e.physical["unmodelled"], orig["unmodelled"]
        changed = {k for k in p if p[k] != orig[k]}
        if v == "no friction":
            assert all(a == 0.0 for a, _, _ in p["friction"])
            assert [w[1:] for w in p["friction"]] == [w[1:] for w in orig["friction"]]  # windows kept
        elif v == "no mismatch":
            assert p["plant"] == orig["model"] != orig["plant"] and p["model"] is None  # the drawn mismatch undone
        elif v == "no noise":
            assert p["noise_std"] == (0.0,) * 4
        elif v == "no valve":
            assert (um.threshold, um.hysteresis, um.delay) == (0.0, 0.0, um0.delay) and um0.threshold > 0
        elif v == "no delay":
            assert um.delay == 0 and um.threshold == um0.threshold and um0.delay > 0
        elif v == "no quantisation":
            assert (um.encoder_counts, um.velocity_step, um.delay) == (0, 0.0, um0.delay)
        else:
            assert not changed
        assert changed <= {"no friction": {"friction"}, "no mismatch": {"plant", "model"},
                           "no noise": {"noise_std"}}.get(v, {"unmodelled"})


def test_reference_and_its_copy_are_one_in_every_variant_and_window(tiny):
    res, learned = tiny
    assert [(b["suite"], list(b["variants"])) for b in res["blocks"]] == [
        (s, list(fl.variant_names(s))) for s in fl.SUITES]
    for b in res["blocks"]:
        for v, figs in b["variants"].items():
            for name in ("clf-n2", "copy"):  # a copy on a variant the reference did not run would not be 1
                assert figs[name]["G"] == 1.0, (b["suite"], v, name)
                assert all(w == 1.0 for w in figs[name]["windows"].values()), (b["suite"], v, name)
            assert figs[learned]["used"] == 2
        # the learned policy differs from the law and the removals change its figure
        gs = [figs[learned]["G"] for figs in b["variants"].values()]
        assert all(math.isfinite(g) for g in gs) and len(set(gs)) > 1 and gs[0] != 1.0


def test_causes_reach_every_policy_on_identical_episodes(tiny):
    res, learned = tiny
    rows = res["rows"]
    by = {(r["policy"], r["suite"], r["episode"]): r for r in rows}
    for name in ("clf-n2", learned):
        noisy = [by[k]["noisy"] for k in by if k[0] == name and fl.variant_of(k[2]) == "no noise"]
        assert noisy and not any(noisy)
        # friction removed: the disturbance windows keep their samples and the law's peak there falls
        pairs = [(by[k], by[(name, k[1], k[2].replace("as is", "no friction"))]) for k in by
                 if k[0] == name and fl.variant_of(k[2]) == "as is"]
        assert all(a["t_disturbance"] == b["t_disturbance"] for a, b in pairs)
        hit = [(a, b) for a, b in pairs if a["t_disturbance"] > 0]
        assert hit and all(b["dst_peak"] < a["dst_peak"] for a, b in hit), name


def test_startup_window_is_the_floored_pair_against_the_law(tiny):
    res, learned = tiny
    rows = res["rows"]
    e = PHYSICAL_FLOORS.error[TASK]
    for b in res["blocks"]:
        ref = {r["episode"]: r for r in rows if r["policy"] == "clf-n2" and r["suite"] == b["suite"]}
        mine = [r for r in rows if r["policy"] == learned and r["suite"] == b["suite"]
                and fl.variant_of(r["episode"]) == "as is"]
        logs = [0.5 * (math.log(max(r["su_rmse"], e) / max(ref[r["episode"]]["su_rmse"], e))
                       + math.log(max(r["su_iae"], 0.2 * e) / max(ref[r["episode"]]["su_iae"], 0.2 * e)))
                for r in mine]
        got = b["variants"]["as is"][learned]["windows"]["startup"]
        assert got == pytest.approx(math.exp(np.mean(logs)), rel=1e-12)
        shares = b["variants"]["as is"][learned]["share"]
        assert sum(shares.values()) == pytest.approx(1.0, rel=1e-9)  # log G is the mean of the class logs


def test_verdict_rule():
    v = fl.verdict(0.9, {"friction": 0.99, "mismatch": 0.95, "noise": 0.85, "valve": 1.05, "delay": 0.9})
    assert v["gap"] == "advantage"
    assert v["explained"] == ["friction", "valve"]  # within 2 % of 1, or across it
    assert v["mostly"] == ["friction", "mismatch", "valve"]  # half of log G or more taken away
    assert v["widens"] == ["noise"]
    assert v["removed_share"]["delay"] == pytest.approx(0.0)
    assert fl.verdict(1.015, {"friction": 2.0})["gap"] == "level"
    across = fl.verdict(0.95, {"delay": 1.24})  # the advantage turned into a larger loss: explained, not widened
    assert across["explained"] == ["delay"] and across["widens"] == [] and across["removed_share"]["delay"] > 1
    loss = fl.verdict(1.5, {"friction": 1.01, "noise": 1.6})
    assert loss["gap"] == "loss" and loss["explained"] == ["friction"] and loss["widens"] == ["noise"]


def test_report_and_flag(tiny, tmp_path):
    res, learned = tiny
    args = build_parser().parse_args(["factors", "--learned", "--episodes", "3"])
    assert args.learned and args.episodes == 3
    path = write_learned_report(res, str(tmp_path), "ehss factors --learned", 1.0)
    text = open(path).read()
    assert text.startswith("# Where the learned") and "Generated by `ehss factors --learned`" in text
    assert "## unmodelled suite, velocity task (2 episodes)" in text and f"- **{learned}**: G " in text
    assert "| policy | as is | no friction | no mismatch | no noise | no valve | no delay | no quantisation |" in text
    csv = (tmp_path / "learned.csv").read_text().splitlines()
    assert csv[0].startswith("suite,task,variant,policy,runs,episodes_used,G,w_startup")
    assert len(csv) == 1 + 3 * (len(fl.variant_names("heldout")) + len(fl.variant_names("unmodelled")))


def test_evaluate_rejects_episodes_outside_its_suites():
    eps = build_episodes(EvalConfig(suites=("heldout",), tasks=(TASK,), heldout_episodes=1))
    with pytest.raises(ValueError, match="episodes must be"):
        evaluate([scripted_spec("clf-n2")], EvalConfig(suites=("unmodelled",), tasks=(TASK,), heldout_episodes=1),
                 workers=1, progress=False, episodes=eps)
