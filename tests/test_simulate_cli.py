"""Issue 16 feature 10: ``ehss simulate`` has the Python API's settings, runs the recommended loop by default,
and exits with documented codes."""

import math
import re

import numpy as np
import pytest

from ehss_gym.cli import build_parser, main
from ehss_gym.cli.simulate import scenario_from_args
from ehss_gym.core.settings import PAPER_FRICTION
from ehss_gym.envs.config import EnvConfig


def _scenario(*argv):
    return scenario_from_args(build_parser().parse_args(["simulate", *argv, "--out", "x"]))


def test_no_settings_runs_the_recommended_loop_and_tracks(tmp_path, capsys):
    rc = main(["simulate", "--out", str(tmp_path / "default")])
    out = capsys.readouterr().out
    assert rc == 0 and "recommended preset" in out and "DIVERGED" not in out
    rmse = float(re.search(r"RMSE\s+(\S+) rad/s", out).group(1))
    assert math.isfinite(rmse) and rmse < 0.01
    sc = _scenario()
    tmpl = EnvConfig.from_kwargs({}).template()
    for k in ("n", "fr", "sigma", "smoothing", "current_limit", "control_period", "substeps", "estimator",
              "estimator_hz"):
        assert getattr(sc, k) == getattr(tmpl, k), k  # the env's defaults, not the printed law


def test_the_paper_preset_diverges_with_the_documented_exit_code(tmp_path, capsys):
    assert main(["simulate", "--preset", "paper", "--out", str(tmp_path / "p")]) == 3
    assert "DIVERGED at t = 0.0003 s" in capsys.readouterr().out
    help_text = build_parser()._subparsers._group_actions[0].choices["simulate"].format_help()
    assert "exit codes: 0 the run tracked; 2 bad arguments; 3 the run diverged" in help_text


def test_settings_override_the_preset():
    sc = _scenario("--preset", "paper", "--sigma", "1e5", "--current-limit", "10", "--estimator", "analog",
                   "--estimator-hz", "500", "--ref-model-hz", "15", "--seed", "7")
    assert (sc.sigma, sc.current_limit, sc.estimator, sc.estimator_hz, sc.ref_model_hz, sc.seed) == \
        (1e5, 10.0, "analog", 500.0, 15.0, 7)
    assert sc.fr == 100.0 and sc.control_period == 1e-4  # the rest from the paper preset
    assert _scenario("--current-limit", "none").current_limit is None


def test_noise_and_mismatch():
    assert _scenario("--noise", "1").noise_std == (1e-5, 1e-4, 2e3, 1e-10)
    assert _scenario("--noise", "0.5").noise_std == (5e-6, 5e-5, 1e3, 5e-11)
    assert _scenario("--noise", "0,1e-3,0,0").noise_std == (0.0, 1e-3, 0.0, 0.0)
    sc = _scenario("--mismatch", "beta=0.8,J=1.25")
    assert sc.plant.beta == pytest.approx(0.8 * 8e8) and sc.plant.J == pytest.approx(0.0625)
    assert sc.model is not None and sc.model.beta == 8e8  # the controller keeps Table I
    assert _scenario().model is None and _scenario().noise_std == (0.0, 0.0, 0.0, 0.0)


@pytest.mark.parametrize("argv,family,value", [
    (["--reference", "step", "--amplitude", "0.5", "--t-step", "1", "--offset", "0.1"], "step",
     [(0.5, 0.1), (1.0, 0.6)]),
    (["--reference", "sine", "--amplitude", "2", "--omega", "3"], "sine", [(0.5, 2 * math.sin(1.5))]),
    (["--reference", "chirp", "--omega-start", "2", "--omega-end", "2", "--offset", "1"], "chirp",
     [(0.25, 1 + math.sin(0.5))]),
    (["--reference", "multisine", "--amplitudes", "1,2", "--omegas", "1,4"], "multisine",
     [(0.3, math.sin(0.3) + 2 * math.sin(1.2))]),
])
def test_references(argv, family, value):
    sc = _scenario(*argv)
    assert sc.reference.family == family
    for t, r in value:
        assert sc.reference(t) == pytest.approx(r, abs=1e-12)


@pytest.mark.parametrize("argv,needle", [
    (["--noise", "x"], "--noise must be 'none', one factor K >= 0 or four stds"),
    (["--noise", "1,2"], "--noise must be"),
    (["--mismatch", "gamma=2"], "--mismatch must be NAME=FACTOR"),
    (["--mismatch", "beta=-1"], "FACTOR > 0"),
    (["--reference", "ramp"], "invalid choice: 'ramp'"),
    (["--omegas", "1,a"], "--omegas must be comma-separated finite numbers"),
    (["--sweep", "3:1"], "--sweep must be START:END"),
    (["--preset", "fast"], "invalid choice: 'fast'"),
    (["--estimator-hz", "0"], "--estimator-hz must be a finite number > 0"),
    (["--seed", "-1"], "--seed must be an integer >= 0"),
])
def test_bad_settings_exit_2_naming_the_parameter(tmp_path, argv, needle, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["simulate", *argv, "--out", str(tmp_path / "x")])
    assert exc.value.code == 2 and needle in capsys.readouterr().err


def test_bad_values_the_scenario_refuses_exit_2(tmp_path, capsys):
    rc = main(["simulate", "--reference", "multisine", "--amplitudes", "1,2", "--omegas", "1", "--out",
               str(tmp_path / "x")])
    assert rc == 2 and "multisine needs 1 to 4 components" in capsys.readouterr().err


def test_a_step_run_prints_its_step_response(tmp_path, capsys):
    rc = main(["simulate", "--reference", "step", "--amplitude", "0.5", "--t-step", "0.5", "--t-end", "1.5",
               "--friction", "none", "--out", str(tmp_path / "s")])
    out = capsys.readouterr().out
    assert rc == 0
    for word in ("step rise time", "step settling time", "step overshoot", "steady-state error"):
        assert word in out


def test_bode_needs_a_broadband_reference(tmp_path, capsys):
    assert main(["simulate", "--bode", "--t-end", "0.5", "--out", str(tmp_path / "b")]) == 2
    assert "--bode needs a broadband reference" in capsys.readouterr().err
    rc = main(["simulate", "--reference", "chirp", "--omega-end", "100", "--t-end", "3", "--friction", "none",
               "--bode", "--out", str(tmp_path / "c")])
    assert rc == 0
    assert (tmp_path / "c_bode.png").stat().st_size > 10_000
    rows = np.loadtxt(tmp_path / "c_bode.csv", delimiter=",", skiprows=2)
    first, second = open(tmp_path / "c_bode.csv").readlines()[:2]
    assert first.startswith("# plant: Table I") and second.startswith("frequency [Hz],magnitude [dB],phase [deg]")
    assert rows.shape[1] == 4 and np.all(np.isfinite(rows))


def test_a_step_run_has_no_friction_unless_asked_so_its_settling_time_is_the_steps(tmp_path, capsys):
    """Before: the paper's friction events (8-10 s) ran with every reference, and a step's settling time was the
    friction's (9.5 s). They belong to the paper's sine run: other references get them only when asked."""
    assert _scenario("--reference", "step").friction == ()
    assert _scenario("--reference", "chirp").friction == () and _scenario("--reference", "multisine").friction == ()
    assert _scenario().friction == PAPER_FRICTION  # the paper's sine run keeps its events
    assert _scenario("--reference", "step", "--friction", "1.8:8:10").friction == ((1.8, 8.0, 10.0),)
    rc = main(["simulate", "--reference", "step", "--t-end", "10", "--out", str(tmp_path / "s")])
    out = capsys.readouterr().out
    assert rc == 0 and "friction none" in out
    settling = float(re.search(r"step settling time\s+(\S+) s", out).group(1))
    assert settling < 0.5  # the step's own response (the 10-90 % rise is about 20 ms)
    help_text = build_parser()._subparsers._group_actions[0].choices["simulate"].format_help()
    assert "none for step, chirp and multisine" in " ".join(help_text.split())
