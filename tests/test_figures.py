"""Issue 16 bug 4: every policy of the comparison has its own colour, and the legends of the crowded figures sit
off the data."""

import csv
import os

import pytest

from ehss_gym import evaluation as ev
from ehss_gym.evaluation import harness
from ehss_gym.reporting import comparison_figures as cf

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_every_policy_of_the_default_comparison_has_its_own_colour():
    """Before: ten colours cycled over the policies (clf-n2 and clf-n6@smoothing=0 shared blue)."""
    names = [s.name for s in harness._complete_specs(ev.default_specs(), ev.EvalConfig(), [])]  # the figures' order
    with open(os.path.join(ROOT, "reports", "comparison", "summary.csv"), newline="") as f:
        assert set(names) <= {r["policy"] for r in csv.DictReader(f)}  # policies of the shipped report
    col = cf._colors(names)
    assert len(set(col.values())) == len(names)
    many = names + [f"extra{i}" for i in range(len(cf.PALETTE) - len(names))]  # as many policies as colours
    assert len(set(cf._colors(many).values())) == len(many) == len(cf.PALETTE) > 10
    sty = cf._styles(names + [f"extra{i}" for i in range(30)])  # past the palette: colour and line style differ
    assert len(set(sty.values())) == len(sty)


@pytest.fixture(scope="module")
def small_results():
    cfg = ev.EvalConfig(suites=("paper", "robustness"), tasks=("velocity",), paper_seconds=8.6, episode_seconds=1.5,
                        friction_levels=(0.0, 3.6), mismatch_levels=(0.0, 0.2), sweep_episodes=1, n_boot=100)
    specs = [ev.scripted_spec("clf-n2"), ev.scripted_spec("clf-n4"), ev.scripted_spec("pid")]
    return ev.evaluate(specs, cfg, workers=1, progress=False)


def _overlaps(a, b) -> bool:
    return a.x0 < b.x1 and b.x0 < a.x1 and a.y0 < b.y1 and b.y0 < a.y1


@pytest.mark.parametrize("figure", ["_robustness", "_paper_traces"])
def test_legends_sit_off_the_data(small_results, figure, monkeypatch, tmp_path):
    made = []
    monkeypatch.setattr(cf, "_finish", lambda fig, res, folder, name, bottom: made.append(fig) or name)
    col = cf._colors([s.name for s in small_results.specs])
    assert getattr(cf, figure)(small_results, str(tmp_path), col, "velocity") is not None
    fig = made[0]
    fig.tight_layout()
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    legends = [a.get_legend() for a in fig.axes if a.get_legend() is not None]
    assert legends
    for leg in legends:
        box = leg.get_window_extent(r)
        for ax in fig.axes:
            assert not _overlaps(box, ax.get_window_extent(r)), f"{figure}: the legend covers an axes"
    cf.plt.close(fig)
