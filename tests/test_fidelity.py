"""`ehss fidelity --quick`: the report renders, the docs block is replaced, and the numbers hold.

The quick run keeps the open loop at 30, 10 and 3 us and runs the closed loop at 30 and 10 us for 2 s. The
checks are the ones the fidelity study exists for: the ZOH top derivative's bias is c0 h/2 (fitted), the FOH
top derivative's error is -c0 h^2/12 v'' and second order, and FOH's closed loop at 30 us tracks 100x better
than ZOH's (velocity: within 1.5x of the analog filters'; position: unsaturated where ZOH is a relay).
"""

import csv
import math
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from ehss_gym.reporting.fidelity import BEGIN, END, replace_block

pytestmark = pytest.mark.xdist_group("fidelity")  # one worker computes the quick fidelity run (a module fixture) once

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("fidelity")
    docs = tmp / "MODEL.md"
    shutil.copy(ROOT / "docs" / "MODEL.md", docs)
    original = docs.read_text(encoding="utf-8")
    out = tmp / "out"
    proc = subprocess.run([sys.executable, "-m", "ehss_gym.cli", "fidelity", "--quick", "--no-progress", "--out",
                           str(out), "--docs", str(docs)], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    return out, original, docs.read_text(encoding="utf-8")


def _rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _block_table(text):
    """{(task, h [us], scheme): cells} from the generated markdown block."""
    block = text[text.index(BEGIN):text.index(END)]
    rows = {}
    for line in block.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 10 and cells[0] in ("velocity", "position"):
            rows[(cells[0], cells[1], cells[2])] = cells
    return rows


def test_files_exist_and_name_the_command(quick_run):
    out, _, _ = quick_run
    for rel in ("FIDELITY.md", "data/open_loop.csv", "data/closed_loop.csv", "figures/order.png"):
        assert (out / rel).is_file() and (out / rel).stat().st_size > 0, rel
    md = (out / "FIDELITY.md").read_text(encoding="utf-8")
    assert "ehss fidelity" in md and "--quick" in md and "QUICK MODE" in md
    assert (out / "figures" / "order.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_docs_block_is_replaced_and_the_rest_kept(quick_run):
    _, original, text = quick_run
    assert text.count(BEGIN) == 1 and text.count(END) == 1
    head, tail = original.split(BEGIN)[0], original.split(END)[1]
    assert text.startswith(head) and text.endswith(tail)  # only the block changed
    block = text[text.index(BEGIN):text.index(END)]
    assert "made by `ehss fidelity" in block.lower()
    assert block != original[original.index(BEGIN):original.index(END)]
    rows = _block_table(text)
    assert len(rows) == 2 * 2 * 3  # two tasks, two periods (quick), three schemes


def test_block_numbers_match_the_data(quick_run):
    out, _, text = quick_run
    rows = _block_table(text)
    for r in _rows(out / "data" / "closed_loop.csv"):
        cells = rows[(r["task"], f"{float(r['h']) * 1e6:g}", r["scheme"])]
        assert float(cells[5]) == pytest.approx(float(r["rmse"]), rel=5e-3)


def test_foh_tracks_100x_better_than_zoh_at_30us_closed_loop(quick_run):
    _, _, text = quick_run
    rows = _block_table(text)
    for task in ("velocity", "position"):
        zoh, foh, analog = (float(rows[(task, "30", s)][5]) for s in ("zoh", "foh", "analog"))
        assert foh * 100 < zoh, (task, foh, zoh)
        if task == "velocity":
            assert foh <= 1.5 * analog, (foh, analog)
        else:  # wave 1's relay: the ZOH position loop is at the current limit on most steps, FOH's on none
            assert float(rows[(task, "30", "zoh")][8]) > 50.0 and float(rows[(task, "30", "foh")][8]) < 1.0


def test_zoh_bias_is_c0_h_over_2_and_foh_error_is_second_order(quick_run):
    out, _, text = quick_run
    ol = _rows(out / "data" / "open_loop.csv")
    top = [r for r in ol if r["top"] == "1"]
    assert len(top) == 2 * 2 * 2 * 3  # tasks x filters x schemes x periods
    for r in top:
        if r["scheme"] == "zoh":
            c0, h = float(r["c0"]), float(r["h"])
            assert float(r["beta"]) == pytest.approx(c0 * h / 2, rel=0.10), r
        else:
            assert float(r["alpha_ratio"]) == pytest.approx(1.0, rel=0.01), r
    # the docs table shows the same fitted ratio for the estimator at 30 us
    rows = _block_table(text)
    for task in ("velocity", "position"):
        assert float(rows[(task, "30", "zoh")][4]) == pytest.approx(1.0, rel=0.10)
    # observed order of the top derivative's error: 1 for zoh, 2 for foh
    for task in ("velocity", "position"):
        for scheme, want in (("zoh", 1.0), ("foh", 2.0)):
            rs = sorted((r for r in top if r["task"] == task and r["filter"] == "estimator" and r["scheme"] == scheme),
                        key=lambda r: float(r["h"]))
            hs, es = [float(r["h"]) for r in rs], [float(r["rel_rms"]) for r in rs]
            slope = math.log(es[-1] / es[0]) / math.log(hs[-1] / hs[0])
            assert slope == pytest.approx(want, abs=0.1), (task, scheme, slope)


def test_missing_markers_are_refused(tmp_path):
    with pytest.raises(ValueError, match="fidelity-table"):
        replace_block("no markers here\n", "x")
    assert replace_block(f"a\n{BEGIN}\nold\n{END}\nb\n", "new") == f"a\n{BEGIN}\nnew\n{END}\nb\n"
    bad = tmp_path / "bad.md"
    bad.write_text("no markers\n", encoding="utf-8")
    proc = subprocess.run([sys.executable, "-m", "ehss_gym.cli", "fidelity", "--quick", "--no-progress",
                           "--out", str(tmp_path / "o"), "--docs", str(bad)], capture_output=True, text=True,
                          timeout=120, cwd=ROOT)
    assert proc.returncode == 2 and "fidelity-table" in proc.stderr
    assert not (tmp_path / "o").exists()  # refused before any work
