"""The README's examples run as written."""

import os
import re
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def readme_block(marker: str, lang: str = "python") -> str:
    """The fenced block right after ``<!-- marker -->`` in README.md."""
    text = open(os.path.join(ROOT, "README.md"), encoding="utf-8").read()
    m = re.search(rf"<!-- {marker} -->\s*```{lang}\n(.*?)```", text, re.S)
    assert m, f"README.md has no {lang} block after <!-- {marker} -->"
    return m.group(1)


def test_first_example_runs_in_a_fresh_interpreter_without_importing_ehss_gym(tmp_path):
    """Issue 16 bug 9: the README's first example works as written, in a fresh process that has not imported
    ehss_gym (Gymnasium 1.x loads no plugin entry points)."""
    code = readme_block("first-example")
    assert not re.search(r"^\s*(import|from)\s+ehss_gym", code, re.M), "the first example must not import ehss_gym"
    check = code + "\nimport sys\nassert env.unwrapped.spec.id == 'EHSSTracking-v0'\nprint('ok', obs.shape)\n"
    r = subprocess.run([sys.executable, "-c", check], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.startswith("ok")


def test_simulator_example_runs_in_the_env_default_loop():
    """The README's simulator example runs as written, on the env's default loop (not a hand-copied one)."""
    from ehss_gym.envs import EnvConfig

    ns: dict = {}
    exec(readme_block("simulator-example"), ns)
    env = EnvConfig.from_kwargs({"task": "velocity"}).template()
    assert all(getattr(ns["sc"], k) == getattr(env, k) for k in EnvConfig.KEYS if k in env.__dataclass_fields__)
    assert [t.scenario.n for t in ns["trajs"]] == [2, 4, 6] and not ns["traj"].metrics()["diverged"]
