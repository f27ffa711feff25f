"""Issue 16 feature 13: the docs site builds with ``mkdocs build --strict`` (a broken reference fails it)."""

import os
import re
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


def _relative_links(path: str) -> list[str]:
    """The relative targets of the markdown links of a page (no URLs, no in-page anchors)."""
    text = open(path, encoding="utf-8").read()
    links = (m.group(1).split("#")[0] for m in re.finditer(r"\]\(([^)\s]+)\)", text))
    return [t for t in links if t and not re.match(r"^[a-z][a-z0-9+.-]*:", t)]


def test_every_relative_link_resolves_in_the_repository_too():
    """Before: docs/reports.md and docs/quickstart/control.md linked the reports by their place on the built site,
    so the links were dead on GitHub and in a checkout. A link is written for the repository; docs/hooks.py maps it
    to the site (the site build above checks that side)."""
    pages = [os.path.join(ROOT, "README.md")] + [
        os.path.join(d, n) for top in ("docs", "reports") for d, _, names in os.walk(os.path.join(ROOT, top))
        for n in names if n.endswith(".md")]
    dead = [(os.path.relpath(p, ROOT), link) for p in pages for link in _relative_links(p)
            if not os.path.exists(os.path.normpath(os.path.join(os.path.dirname(p), link)))]
    assert len(pages) > 15 and not dead, dead
