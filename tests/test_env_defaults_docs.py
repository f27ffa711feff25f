"""The env's defaults as the docs show them: one table generated from the code, and the statements about the loop
the shipped models act in."""

import glob
import json
import os
import shutil

import pytest

import ehss_gym.envs.config as ec
from ehss_gym.agents.specs import PINNED_ENV_KEYS, env_kwargs_for, get_spec, resolved_env_kwargs
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


def shipped_loop_mismatches(folder: str) -> list[str]:
    """The shipped models in ``folder`` whose pinned settings are not the env's defaults for their task and n with
    their agent's recipe (:func:`ehss_gym.agents.specs.resolved_env_kwargs` of the agent's training env), each with
    the settings that differ."""
    out = []
    for f in sorted(glob.glob(os.path.join(folder, "*.json"))):
        cfg = json.load(open(f))
        kw = cfg["env_kwargs"]
        spec = get_spec(cfg["metadata"]["agent_spec"]["name"])
        want = resolved_env_kwargs(env_kwargs_for(spec, kw["task"], kw["n"]))
        bad = sorted(k for k in (*PINNED_ENV_KEYS, "unmodelled_effects") if kw.get(k) != want.get(k))
        if bad:
            out.append(f"{os.path.basename(f)}: {bad}")
    return out


def test_shipped_models_act_in_todays_loop_as_the_docs_say():
    """docs/ENV.md and agents/specs.py: every shipped model was trained with its agent's recipe in today's loop (the
    env's defaults for its task and n); a change of the defaults or the recipe makes them stale (retrain and ship)."""
    assert glob.glob(os.path.join(ROOT, "ehss_gym", "models", "*.json"))
    assert shipped_loop_mismatches(os.path.join(ROOT, "ehss_gym", "models")) == []


def test_a_model_of_another_loop_is_found(tmp_path, monkeypatch):
    """The check above can fail: a shipped file that pins another law setting is named with that setting."""
    src = sorted(glob.glob(os.path.join(ROOT, "ehss_gym", "models", "*.json")))[0]
    cfg = json.load(open(src))
    cfg["env_kwargs"]["sigma"] *= 2
    (tmp_path / "m.json").write_text(json.dumps(cfg))
    assert shipped_loop_mismatches(str(tmp_path)) == ["m.json: ['sigma']"]
