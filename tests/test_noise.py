"""The noise study (``ehss noise``): its coded rules each side, the "state" estimator's bias derived against
measured, the quick report, and the env's defaults against the study's committed choice."""

from __future__ import annotations

import json
import math
import pathlib
import re

import pytest

from ehss_gym.cli import main
from ehss_gym.core.laws import lin_sontag, sontag
from ehss_gym.core.sim import simulate_batch
from ehss_gym.envs import DEFAULTS
from ehss_gym.envs.config import BUMPLESS_DEFAULT
from ehss_gym.study.noise import bias_check, bias_scenarios, ls_sigma0
from ehss_gym.study.noise_config import NoiseStudyConfig
from ehss_gym.study.noise_rules import choose_estimator_law, choose_ls_sigma, choose_startup, is_lost, summary

ROOT = pathlib.Path(__file__).parents[1]


def _cell(rmse_quiet=1e-3, fric=1e-2, tv=1e3, sat=0.0, n_lost=0):
    return {"rmse_quiet": rmse_quiet, "fric": fric, "tv": tv, "sat": sat, "n_lost": n_lost}


def test_is_lost_each_side():
    assert not is_lost({"window_rms_max": 0.29}, 0.3)
    assert is_lost({"window_rms_max": 0.31}, 0.3)
    assert is_lost({"diverged": True, "window_rms_max": 0.0}, 0.3)


def test_summary_counts_lost_and_medians():
    recs = [{"rmse_true": 1.0, "tv_u_rate": 10.0, "saturation": 0.1, "window_rms_max": 0.0},
            {"rmse_true": 3.0, "tv_u_rate": 30.0, "saturation": 0.3, "window_rms_max": 1.0},
            {"diverged": True, "saturation": 0.5}]
    s = summary(recs, 0.3)
    assert s["rmse"] == 2.0 and s["tv"] == 20.0 and s["n_lost"] == 2 and s["n"] == 3
    assert s["sat"] == pytest.approx(0.3)


def test_choose_startup_prefers_fewest_lost_then_fewest_levers():
    t = {"old": {"levers": 0, "n_lost": 5, "rmse": 0.1}, "B": {"levers": 1, "n_lost": 0, "rmse": 0.2},
         "P+B": {"levers": 2, "n_lost": 0, "rmse": 0.05}}
    assert choose_startup(t) == "B"
    t["P+B"]["n_lost"] = -1  # (impossible, but the order of the keys is what is checked)
    assert choose_startup(t) == "P+B"


def test_choose_ls_sigma_excludes_lost_and_scores_against_sontag():
    ref = [_cell(tv=100.0), _cell(tv=100.0)]
    cells = {1e5: [_cell(tv=10.0), _cell(tv=10.0, n_lost=1)],  # the best score, but loses an episode
             1e6: [_cell(tv=50.0), _cell(tv=50.0)],
             1e7: [_cell(rmse_quiet=3e-3, tv=20.0), _cell(rmse_quiet=3e-3, tv=20.0)]}
    # scores: 1e6: 0.5 * 1 + 0.5 * 0.5 = 0.75; 1e7: 0.5 * 3 + 0.5 * 0.2 = 1.6
    assert choose_ls_sigma(cells, ref) == 1e6
    cells[1e6][0]["n_lost"] = 2
    cells[1e7][1]["n_lost"] = 1
    assert choose_ls_sigma(cells, ref) == 1e5  # none admissible: the fewest lost (1e5 and 1e7 tie), best score


def test_choose_estimator_law_each_side():
    rows = ("0x", "1x")
    def pair(**kw1):
        return {"0x": _cell(), "1x": _cell(**kw1)}
    cells = {("svf", "sontag"): pair(tv=6e4),
             ("state", "sontag"): pair(tv=1e2, fric=0.1),  # lowest TV, but its friction peak is 10x the best
             ("eso", "sontag"): pair(tv=5e2),
             ("eso", "lin-sontag"): pair(tv=4e2, n_lost=1),  # loses an episode at 1x: not admissible
             ("svf", "lin-sontag"): pair(tv=3e2, sat=0.02)}  # saturates above max_sat: not admissible
    chosen, adm, kept = choose_estimator_law(cells, rows, "1x", "0x", 2.0, 0.01)
    assert chosen == ("eso", "sontag")
    assert set(adm) == {("svf", "sontag"), ("state", "sontag"), ("eso", "sontag")}
    assert ("state", "sontag") not in kept
    chosen, adm, _ = choose_estimator_law({k: v for k, v in cells.items() if k[1] == "lin-sontag"}, rows, "1x",
                                          "0x", 2.0, 0.01)
    assert chosen is None and adm == []


def test_ls_sigma0_matches_the_gains_near_zero():
    """sigma_LS = sigma (U^2/2)^(1/n): at it Lin-Sontag's small-s gain equals Sontag's (docs/MODEL.md, "Laws")."""
    for n in (2, 4, 6):
        sl = ls_sigma0(1e5, 10.0, n)
        s, G = 1e-3, 2.0
        assert lin_sontag(0.0, G, s, n, sl, 0.0, 10.0) == pytest.approx(sontag(0.0, G, s, n, 1e5, 0.0), rel=1e-6)


@pytest.mark.parametrize("task", ["velocity", "position"])
def test_state_estimators_bias_derived_against_measured(task):
    """Under -20 %, 0 and +20 % mismatch (beta, J, B, c_sm, P_s of the plant) and friction, the closed-form bias of
    the "state" estimator's x2' and x2'' (study/bias.py) matches the logged estimate minus central differences of
    the true states to 1e-2 of its RMS (measured: <= 1.3e-3). The mismatch shows: outside friction the mismatched runs'
    error is far from the nominal run's (which the estimator makes exact up to the discretisation)."""
    cfg = NoiseStudyConfig(bias_t_end=0.6)
    cases = bias_scenarios(cfg, task)
    assert [c[0] for c in cases] == ["0.8", "1", "1.2"]
    res = {label: bias_check(tr) for (label, _), tr in zip(cases, simulate_batch([c[1] for c in cases]))}
    for label, r in res.items():
        assert r["b1_agree"] < 1e-2 and r["b2_agree"] < 1e-2 and r["bs_agree"] < 1e-2, (label, r)
        assert r["b1_rms"] > 1.0  # a bias there is to check (friction alone: T_f/J = 36 rad/s^2 while on)
    # measured: velocity 8e-7 nominal against 3.4e-3 / 3.9e-3 rad/s mismatched; position 1e-9 against 7e-5 / 1e-5 rad
    assert res["1"]["e_off_rms"] < 1e-2 * min(res["0.8"]["e_off_rms"], res["1.2"]["e_off_rms"])
    # the friction offset the derivation predicts, -b_s/lambda_0, has the measured sign
    for r in res.values():
        assert r["e_pred_fric"] * r["e_fric"] > 0


def test_noise_rejects_bad_out(tmp_path):
    f = tmp_path / "file.txt"
    f.write_text("x")
    assert main(["noise", "--quick", "--out", str(f), "--no-progress"]) == 2
    assert main(["noise", "--quick", "--out", " ", "--no-progress"]) == 2


def test_quick_noise_report_renders(tmp_path):
    out = tmp_path / "noise"
    assert main(["noise", "--quick", "--out", str(out), "--no-progress", "--store", str(tmp_path / "jobs")]) == 0
    text = (out / "REPORT.md").read_text()
    assert "ehss noise --quick" in text and "QUICK MODE" in text
    assert not re.search(r"\bnan\b", text, re.I)
    for link in set(re.findall(r"\]\((figures/[^)]+\.png)\)", text)):
        assert (out / link).stat().st_size > 5_000, link
    rec = json.loads((out / "recommended.json").read_text(),
                     parse_constant=lambda c: pytest.fail(f"non-finite {c} in JSON"))
    assert rec["quick_mode"] is True
    for task in ("velocity", "position"):
        assert {"estimator", "law", "sigma", "layer_gain", "bumpless", "ref_accel"} <= set(rec[task])


def test_env_defaults_are_the_noise_studys_choice():
    """DEFAULTS restate reports/noise/recommended.json (made by `ehss noise`): per task the estimator and its
    bandwidths, the law (and each other law's sigma), the reference shaper. The default law's sigma and boundary
    layer are the baselines' tuning (tests/test_baselines.py), and the bumpless start the evaluation ruler's choice
    (BUMPLESS_DEFAULT, documented in envs/config.py): on for both tasks, whatever the noise study recorded."""
    rec = json.loads((ROOT / "reports/noise/recommended.json").read_text())
    assert not rec["quick_mode"]
    assert DEFAULTS.pressure_domain == rec["pressure_domain"]
    assert BUMPLESS_DEFAULT is True
    for task in ("velocity", "position"):
        td, r = getattr(DEFAULTS, task), rec[task]
        for key in ("estimator", "estimator_hz", "observer_hz", "law", "ref_accel"):
            assert getattr(td, key) == r[key], (task, key)
        assert td.bumpless is BUMPLESS_DEFAULT, task
        assert dict(td.sigma_by_law) == {k: v for k, v in r["sigma_by_law"].items() if k != td.law}, task
        assert math.isfinite(td.sigma)
