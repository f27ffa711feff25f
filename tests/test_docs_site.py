"""Issue 16 feature 13: the docs site builds with ``mkdocs build --strict`` (a broken reference fails it)."""

import importlib.util
import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

needs_mkdocs = pytest.mark.skipif(
    importlib.util.find_spec("mkdocs") is None or importlib.util.find_spec("mkdocstrings") is None,
    reason="mkdocs and mkdocstrings are not installed: pip install -e '.[docs]' (the README's test command does)")


@needs_mkdocs
def test_the_site_builds_strictly(tmp_path):
    site = tmp_path / "site"
    r = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)], cwd=ROOT,
                       capture_output=True, text=True, timeout=600, env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    api = (site / "api" / "env" / "index.html").read_text(encoding="utf-8")
    assert "EHSSTrackingEnv" in api and "terminate_on_lost_track" in api  # generated from the docstrings
    assert (site / "reports" / "comparison" / "REPORT" / "index.html").is_file()
    assert (site / "reports" / "bode" / "chirp_velocity_bode.png").is_file()
    model = (site / "MODEL" / "index.html").read_text(encoding="utf-8")
    assert "Digital filters" in model
