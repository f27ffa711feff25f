"""Issue 16 feature 13: the docs site builds with ``mkdocs build --strict`` (a broken reference fails it)."""

import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


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
