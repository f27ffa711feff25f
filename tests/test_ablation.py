"""The ablation's rule (ehss_gym.study.ablation.rank), its cells and its report, on made-up results (no training)."""

import csv
import io
import os

from ehss_gym.reporting import ablation as report
from ehss_gym.study import ablation as ab


def row(figure, failed=False, n_failed=0):
    """A validation row as :func:`ehss_gym.evaluation.heldout.relative_scores` returns it."""
    return {"figure": figure, "failed": failed, "n_failed": n_failed, "tracking": figure, "disturbance": 1.0,
            "effort": 1.0, "chatter": 1.0}


def result(cell, u, h, u0=1.0, h0=1.0, u_failed=False, h_failed=False):
    """A finished cell's numbers as :func:`ehss_gym.study.ablation.cell_result` returns them."""
    U, H = row(u, u_failed, int(u_failed)), row(h, h_failed, int(h_failed))
    return {"cell": cell, "label": cell.label, "run_dir": "x", "best": u, "best_step": 50_000,
            "best_is_untrained": False, "timesteps": 300_000, "cpu_s": 120.0, "wall_s": 150.0,
            "history": [{"step": 0, "figure": u0, "failed": False, "n_failed": 0},
                        {"step": 300_000, "figure": u, "failed": u_failed, "n_failed": int(u_failed)}],
            "U": U, "U0": row(u0), "H": H, "H0": row(h0), "final": u, "step0": u0, "heldout": h,
            "beats_step0": u < u0}


CELLS = ab.stage1()


def test_stage_cells():
    assert len(CELLS) == 8 and len({c.label for c in CELLS}) == 8
    second = ab.stage2(CELLS[:2])
    assert len(second) == 10 and len({c.label for c in second + CELLS}) == 18
    dcomp_mix = [c for c in second if c.base == "dcomp" and c.distribution == "mixture"][0]
    env = dcomp_mix.hp()["env_kwargs"]
    assert env["reference_delay"] == 1.0 and env["unmodelled_share"] == 0.5 and env["unmodelled_effects"]
    assert ab.stage2(CELLS[:1])[0].hp()["exploration"] == "gsde"


def test_stage3_puts_the_leader_on_the_distribution_it_has_not_trained_on():
    lead = ab.Cell("physical", "schedule")
    (third,) = ab.stage3(lead, {c.label for c in CELLS})
    assert (third.reward, third.action, third.exploration, third.base) == ("physical", "schedule", "gaussian", "law")
    env = third.hp()["env_kwargs"]
    assert third.distribution == "mixture" and env["unmodelled_share"] == 0.5 and env["unmodelled_effects"]
    assert ab.stage3(lead, {third.label}) == []  # already run in stage 2: nothing new
    assert [c.distribution for c in ab.stage3(third, set())] == ["unmodelled"]


def test_sets_draw_with_and_without_the_effects():
    kw = ab.Cell("class", "current", distribution="mixture").config("/tmp/never-written").env_kwargs()
    assert ab.set_kwargs(kw, "U")["unmodelled_share"] == 1.0 and ab.set_kwargs(kw, "U")["unmodelled_effects"]
    assert not ab.set_kwargs(kw, "H")["unmodelled_effects"] and "unmodelled_share" not in ab.set_kwargs(kw, "H")


def test_rank_admissible_first_ties_broken_by_h():
    a = result(CELLS[0], 0.80, 1.04)   # admissible, leads on U
    b = result(CELLS[1], 0.81, 0.90)   # admissible, within 2 % of a: ties, lower H -> first
    c = result(CELLS[2], 0.60, 1.20)   # best U but H above the gate: not admissible
    d = result(CELLS[3], 0.50, 0.95, u_failed=True)  # fails the gate on U: not admissible, after c
    e = result(CELLS[4], 0.90, 1.00)   # admissible, outside the tie
    f = result(CELLS[5], 0.70, 1.00, h_failed=True)  # fails the gate on H: not admissible
    order = [r["label"] for r in ab.rank([a, b, c, d, e, f])]
    assert order == [b["label"], a["label"], e["label"], c["label"], f["label"], d["label"]]
    assert [ab.admissible(r) for r in (a, b, c, d, e, f)] == [True, True, False, False, True, False]
    # stage 2's pick is by U alone, the failure gate first
    assert [r["label"] for r in ab.by_u([a, b, c, d])[:2]] == [c["label"], a["label"]]


def test_tie_is_relative_to_the_leader():
    a, b = result(CELLS[0], 0.800, 1.0), result(CELLS[1], 0.800 * 1.021, 0.5)
    assert [r["label"] for r in ab.rank([a, b])] == [a["label"], b["label"]]  # 2.1 % behind: no tie


def test_report_renders_the_study(tmp_path):
    res = [result(CELLS[0], 0.80, 1.04), result(CELLS[1], 1.20, 0.90, h_failed=True)]
    second = [result(ab.stage2(CELLS[:1])[2], 0.55, 1.3, u0=0.67, h0=1.79)]
    (lead_mix,) = ab.stage3(CELLS[0], {r["label"] for r in res + second})
    third = [result(lead_mix, 0.81, 0.99)]  # ties with the leader on U, lower H: it wins
    cells = res + second + third
    study = ab.Ablation(ab.rank(res), second, third, ab.rank(cells), ["some-cell"],
                        {"U": row(0.67), "H": row(1.79)}, {r["label"]: "ehss train ..." for r in cells})
    files = report.write_report(study, str(tmp_path), "ehss ablation --runs R --out O")
    text = (tmp_path / "ABLATION.md").read_text()
    assert len(files) == 3 and (tmp_path / "curves.png").stat().st_size > 0
    assert f"Winner by the rule: `{lead_mix.label}`" in text
    assert "## Stage 3: the leader of stages 1-2 on the other training distribution" in text
    assert "dcomp-n2 0.670 on U" in text and "Not finished (not in the tables): some-cell" in text
    assert "1 of 4 cells end below dcomp-n2 on U (0.670)" in text and "FAILED (1)" in text
    rows = list(csv.reader(io.StringIO((tmp_path / "ablation.csv").read_text())))
    assert tuple(rows[0]) == report.CSV_COLUMNS and len(rows) == 1 + 2 * 4
    assert rows[1][:6] == [CELLS[0].label, "class", "current", "gaussian", "law", "unmodelled"]


def test_undefined_figure_is_not_admissible():
    r = result(CELLS[0], 0.8, 1.0)
    r["final"] = r["U"]["figure"] = None
    assert not ab.admissible(r)


def test_the_ablation_pins_mkl_before_it_rescores_a_policy(tmp_path, monkeypatch):
    """run_ablation re-scores each cell's policy with torch: MKL's code path is pinned first, as in training and in
    the harness (unpinned, an AVX-512 CPU's float32 kernels moved one cell's figure from 1.0228 to 1.0322)."""
    from ehss_gym.infra.execution import BLAS_ENV

    for key in BLAS_ENV:
        monkeypatch.delenv(key, raising=False)
    monkeypatch.setattr(ab, "scripted_on_validation", lambda env_kwargs: {})  # episodes: not what this test is about
    study = ab.run_ablation(str(tmp_path), train=False, progress=False)
    assert study.order == [] and all(os.environ.get(k) == v for k, v in BLAS_ENV.items())
