"""The env's defaults as the docs show them: one table generated from the code, and the statements about the loop
the shipped models act in."""

import glob
import json
import os
import shutil

import pytest

import ehss_gym.envs.config as ec
from ehss_gym.envs import defaults
from ehss_gym.envs.config import EnvConfig, defaults_table

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_committed_tables_equal_the_code():
    """README.md, docs/ENV.md and the env's docstring hold today's table (else: python -m ehss_gym.envs.defaults
    --write)."""
    assert defaults.stale() == []
    from ehss_gym.envs.env import EHSSTrackingEnv

    assert defaults_table().splitlines()[2].strip() in EHSSTrackingEnv.__doc__


def test_a_changed_default_makes_the_committed_tables_stale(monkeypatch):
    # a setting of the task's defaults (the law's sigma, f_r, smoothing and layer come from the tuned per-n table)
    moved = ec.EnvDefaults(velocity=ec.TaskDefaults(**{**ec.DEFAULTS.velocity.__dict__, "observer_hz": 150.0}))
    monkeypatch.setattr(ec, "DEFAULTS", moved)
    assert "| `observer_hz` | 150 | " in defaults_table()
    assert sorted(defaults.stale()) == sorted(defaults.FILES)


def test_the_table_lists_every_setting_with_each_tasks_value():
    table = defaults_table()
    for key in EnvConfig.KEYS:
        if key != "task":
            assert f"| `{key}" in table, key
    for task in ("velocity", "position"):
        cfg = EnvConfig.from_kwargs({"task": task})
        assert f'`"{cfg.estimator}"`' in table
    row = next(ln for ln in table.splitlines() if ln.startswith("| `control_period` |"))
    assert row.split("|")[2].strip() == f"{EnvConfig.from_kwargs({}).control_period:.0e}".replace("e-0", "e-")


def test_write_rewrites_only_the_marked_blocks(tmp_path, monkeypatch):
    for rel in defaults.FILES:
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(os.path.join(ROOT, rel), tmp_path / rel)
    readme = tmp_path / "README.md"
    text = readme.read_text()
    stale_text = text.replace("| `fr` |", "| `fr` (stale) |")
    readme.write_text(stale_text)
    assert defaults.stale(tmp_path) == ["README.md"]
    monkeypatch.setattr(defaults, "ROOT", tmp_path)
    assert defaults.main(["--write"]) == 0
    assert readme.read_text() == text and defaults.stale(tmp_path) == []
    assert defaults.main([]) == 0
    readme.write_text(text.replace("<!-- env-defaults:end -->", ""))
    assert defaults.main([]) == 1
    with pytest.raises(ValueError, match="found 0"):
        defaults.rewrite("no block here", "")


def test_shipped_models_act_in_the_loop_the_docs_describe():
    """docs/ENV.md and agents/specs.py: the shipped models pin the SVF, no adaptive layer, no pressure domain, no
    shaper, the paper's start, the plain law and a 1 ms agent period."""
    files = sorted(glob.glob(os.path.join(ROOT, "ehss_gym", "models", "*.json")))
    assert files
    for f in files:
        kw = json.load(open(f))["env_kwargs"]
        assert (kw["estimator"], kw["layer_gain"], kw["pressure_domain"], kw["ref_accel"], kw["bumpless"],
                kw["smoothing"], kw["agent_period"]) == ("foh", 0.0, None, 0.0, False, 0.0, 20), f
