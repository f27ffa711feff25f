"""Issue 16 bug 4: every policy of the comparison has its own colour, and the legends of the crowded figures sit
off the data."""

import csv
import os
import warnings

import pytest

from ehss_gym import evaluation as ev
from ehss_gym.evaluation import harness
from ehss_gym.reporting import comparison_figures as cf

pytestmark = pytest.mark.xdist_group("figures")  # one worker computes the small evaluation (a module fixture) once

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


LONG = "clf-n2@smoothing=0,estimator=foh,layer_gain=0,ref_accel=0,pressure_domain=none"  # a matched law's label


@pytest.fixture(scope="module")
def long_named_results():
    """A comparison with the longest policy name the default report holds (a law at a learned policy's settings)."""
    cfg = ev.EvalConfig(suites=("heldout", "paper"), tasks=("velocity",), heldout_episodes=2, episode_seconds=0.3,
                        paper_seconds=0.3, n_boot=100)
    over = {"smoothing": 0.0, "estimator": "foh", "layer_gain": 0.0, "ref_accel": 0.0, "pressure_domain": None}
    specs = [ev.scripted_spec("clf-n2"), ev.scripted_spec("clf-n4"), ev.scripted_spec("pid"),
             ev.scripted_spec("clf-n2", label=LONG, env_overrides=over)]
    return ev.evaluate(specs, cfg, workers=1, progress=False)


def test_every_text_of_the_comparison_figures_lies_inside_the_canvas(long_named_results, monkeypatch, tmp_path):
    """Before: the score figures cut their titles and x-labels ('lower is bette') at the canvas edge, and matplotlib
    warned that the tight layout could not be applied (the long policy names took the panels' width)."""
    saved, close = [], cf.plt.close
    monkeypatch.setattr(cf.plt, "close", lambda fig: saved.append(fig))  # kept open to be inspected below
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        made = cf.make_figures(long_named_results, str(tmp_path))
    assert not [w for w in caught if "ayout" in str(w.message)], [str(w.message) for w in caught]
    assert made["pareto"] and made["metrics"] and len(saved) >= 4
    for fig in saved:
        fig.canvas.draw()
        r = fig.canvas.get_renderer()
        drawn = fig.get_tightbbox(r)  # [in] every artist drawn: titles, labels, tick labels in view, legends, footer
        w, h = fig.get_size_inches()
        tol = 1.0 / fig.dpi  # one pixel
        what = fig._suptitle.get_text() if fig._suptitle else fig.axes[0].get_title()
        assert drawn.x0 >= -tol and drawn.y0 >= -tol and drawn.x1 <= w + tol and drawn.y1 <= h + tol, \
            f"{what!r}: drawn over {drawn.bounds}, canvas {w:.2f} x {h:.2f} in"
        for ax in fig.axes:
            for text in (ax.title, ax.xaxis.label, *fig.texts):
                box = text.get_window_extent(r)
                assert not text.get_text() or (box.x0 >= -1 and box.x1 <= fig.bbox.x1 + 1), text.get_text()
        close(fig)
