"""The command line speaks one language: one name per concept, defaults and choices in every help, a description
for every command, old names that still work (with a warning) for one release, and help and argument errors that
answer without loading the simulator, the env or the agents."""

import json
import subprocess
import sys

import pytest

from ehss_gym.cli import COMMANDS, build_parser, main
from ehss_gym.core.registry import ESTIMATORS, LAWS, names

HEAVY = ("numba", "torch", "gymnasium", "stable_baselines3", "matplotlib", "scipy")
PROBE = f"""
import json, sys
from ehss_gym.cli import main
try:
    main(sys.argv[1:])
except SystemExit as exc:
    code = exc.code
print(json.dumps({{"code": code, "loaded": [m for m in {HEAVY!r} if m in sys.modules]}}))
"""


@pytest.mark.parametrize("argv", [["--help"], ["simulate"], ["evaluate", "--help"], ["train", "--task", "torque"],
                                  ["noise", "--workers", "2"]])
def test_help_and_argument_errors_load_nothing_heavy(argv):
    """``ehss --help``, a command's help and a bad argument answer from the options alone (a fresh interpreter)."""
    r = subprocess.run([sys.executable, "-c", PROBE, *argv], capture_output=True, text=True, timeout=120)
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert out["code"] in (0, 2), r.stderr
    assert out["loaded"] == [], f"ehss {' '.join(argv)} imported {out['loaded']}"
    if argv == ["simulate"]:
        assert "the following arguments are required: --out" in r.stderr


def test_every_command_has_a_description_and_every_option_its_default():
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    assert sorted(sub.choices) == sorted(c.name for c in COMMANDS)
    for name, p in sub.choices.items():
        assert p.description, name
        text = p.format_help()
        for action in p._actions:
            shown = action.default not in (None, False) and action.help not in (None, "==SUPPRESS==")
            if shown and action.option_strings and action.dest not in ("help", "module"):
                assert "default" in p.formatter_class(name)._get_help_string(action), (name, action.dest)
        one_process = ("simulate", "reproduce", "noise", "factors", "baselines", "bench", "fidelity", "plant", "warmup")
        assert "--workers" in text or name in one_process, name


def test_choices_come_from_the_tables():
    help_text = build_parser().parse_known_args(["simulate", "--out", "x"])[0]  # parses
    assert help_text.estimator is None
    sim = next(a for a in build_parser()._actions if a.dest == "command").choices["simulate"]
    est = next(a for a in sim._actions if a.dest == "estimator")
    law = next(a for a in sim._actions if a.dest == "law")
    assert tuple(est.choices) == names(ESTIMATORS) and tuple(law.choices) == names(LAWS)
    for row in ESTIMATORS:
        assert row.name in est.help and row.doc.split(",")[0] in est.help


def test_train_help_shows_choices_and_a_readable_no_progress():
    train = next(a for a in build_parser()._actions if a.dest == "command").choices["train"]
    text = train.format_help()
    assert "--task {velocity,position}" in text and "--backend {local,ray}" in text
    no_progress = next(a for a in train._actions if "--no-progress" in a.option_strings)
    assert no_progress.help.startswith("turn off")


@pytest.mark.parametrize("argv, dest, value, old, new", [
    (["evaluate", "--tasks", "position"], "task", ("position",), "--tasks", "--task"),
    (["train", "--jobs", "3"], "workers", "3", "--jobs", "--workers"),
    (["tune", "--cpus", "3"], "workers", 3, "--cpus", "--workers"),
    (["training-report", "--noise", "x.json"], "exploration", "x.json", "--noise", "--exploration"),
])
def test_old_option_names_still_work_with_a_deprecation_warning(argv, dest, value, old, new, capsys):
    args = build_parser().parse_args(argv)
    assert getattr(args, dest) == value
    err = capsys.readouterr().err
    assert f"warning: {old} is deprecated and will be removed in the next release; use {new}" in err


def test_one_name_per_concept():
    """--workers for parallel jobs, --task for the task(s); the old names are hidden from the help."""
    commands = next(a for a in build_parser()._actions if a.dest == "command").choices
    for name, p in commands.items():
        text = p.format_help()
        for old in ("--jobs", "--cpus", "--tasks"):
            assert old not in text, (name, old)


def test_noise_runs_on_the_execution_layer(tmp_path, capsys):
    """``ehss noise`` takes --backend and --store like the other studies; a bad backend exits 2 naming it."""
    assert main(["noise", "--quick", "--out", str(tmp_path / "n"), "--backend", "ray", "--address", "nowhere"]) == 2
    assert "--address must be HOST:PORT" in capsys.readouterr().err
