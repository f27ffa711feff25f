"""`ehss simulate`: outputs, summary and argument errors (exit code 2 naming the parameter)."""

import subprocess
import sys

import numpy as np
import pytest

from ehss_gym.cli import main
from ehss_gym.core.params import PlantParams


def test_simulate_writes_png_npz_csv_and_summary(tmp_path, capsys):
    out = tmp_path / "run"
    rc = main(["simulate", "--n", "4", "--sigma", "1e5", "--current-limit", "10", "--t-end", "0.5",
               "--friction", "1.8:0.2:0.3", "--out", str(out)])
    assert rc == 0
    text = capsys.readouterr().out
    for word in ("RMSE", "max |e|", "in friction", "IAE", "control TV", "saturation fraction"):
        assert word in text
    data = np.load(f"{out}.npz")
    for name in ("t", "y", "y_ref", "e", "u", "u_applied", "s"):
        assert name in data and len(data[name]) == 500
    first, second = open(f"{out}.csv").readlines()[:2]
    assert first.startswith("# plant: Table I (built in, #") and "controller's model: the plant's parameters" in first
    header = second.strip().split(",")
    assert header[:7] == ["t [s]", "y [rad/s]", "y_ref [rad/s]", "e [rad/s]", "u [mA]", "u_applied [mA]",
                          "u_base [mA]"]  # the CSV header carries units
    csv = np.loadtxt(f"{out}.csv", delimiter=",", skiprows=2)
    assert str(data["plant"]).startswith("Table I") and data["plant_values"].tolist() == list(PlantParams())
    np.testing.assert_allclose(csv[:, header.index("e [rad/s]")], data["e"], rtol=1e-9, atol=1e-15)
    assert (tmp_path / "run.png").stat().st_size > 10_000


def test_simulate_reports_divergence(tmp_path, capsys):
    rc = main(["simulate", "--preset", "paper", "--t-end", "0.05", "--out", str(tmp_path / "d")])
    assert rc == 3  # the documented exit code of a diverged run
    assert "DIVERGED at t =" in capsys.readouterr().out
    assert np.all(np.isfinite(np.load(tmp_path / "d.npz")["y"]))


@pytest.mark.parametrize("args,needle", [
    (["--friction", "1.8:8"], "--friction must be AMP:START:END"),
    (["--friction", "a:b:c"], "--friction must be AMP:START:END"),
    (["--friction", "1.8:10:8"], "END > START"),
    (["--friction=-1:8:10"], "AMP >= 0"),
    (["--n", "3"], "--n must be an even integer"),
    (["--n", "0"], "--n must be an even integer"),
    (["--substeps", "0"], "--substeps must be an integer >= 1"),
    (["--control-period=-1e-4"], "--control-period must be a finite number > 0"),
    (["--control-period", "nan"], "--control-period must be a finite number > 0"),
    (["--t-end", "0"], "--t-end must be a finite number > 0"),
    (["--sigma", "inf"], "--sigma must be a finite number > 0"),
    (["--fr", "-3"], "--fr must be a finite number > 0"),
    (["--smoothing", "-1"], "--smoothing must be a finite number >= 0"),
    (["--current-limit", "abc"], "--current-limit must be 'none' or a finite number > 0"),
    (["--current-limit", "0"], "--current-limit must be 'none' or a finite number > 0"),
    (["--task", "torque"], "invalid choice"),
    (["--estimator", "bilinear"], "argument --estimator: invalid choice: 'bilinear'"),
])
def test_bad_arguments_exit_2_and_name_the_parameter(tmp_path, args, needle, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["simulate", *args, "--out", str(tmp_path / "x")])
    assert exc.value.code == 2
    assert needle in capsys.readouterr().err


def test_t_end_shorter_than_control_period_is_a_cli_error(tmp_path, capsys):
    rc = main(["simulate", "--preset", "paper", "--t-end", "1e-5", "--out", str(tmp_path / "x")])
    assert rc == 2
    assert "t_end must be >= control_period" in capsys.readouterr().err


def test_console_script_entry_point():
    r = subprocess.run([sys.executable, "-m", "ehss_gym.cli", "--version"], capture_output=True, text=True)
    assert r.returncode == 0 and "ehss-gym" in r.stdout


def test_simulate_takes_the_estimator(tmp_path, capsys):
    for scheme in ("zoh", "analog"):
        assert main(["simulate", "--estimator", scheme, "--sigma", "1e5", "--current-limit", "10", "--t-end", "0.05",
                     "--control-period", "3e-5", "--substeps", "1", "--out", str(tmp_path / scheme)]) == 0
        assert f"estimator={scheme}" in capsys.readouterr().out


def test_friction_none_disables_friction(tmp_path, capsys):
    """Issue 16 bug 2: ``--friction none`` (as the help says) runs without friction events."""
    rc = main(["simulate", "--friction", "none", "--t-end", "0.05", "--out", str(tmp_path / "nf")])
    assert rc == 0
    assert np.all(np.load(tmp_path / "nf.npz")["friction"] == 0.0)


def test_friction_none_cannot_be_mixed_with_events(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["simulate", "--friction", "none", "1.8:8:10", "--out", str(tmp_path / "x")])
    assert exc.value.code == 2
    assert "--friction none cannot be combined with events" in capsys.readouterr().err
