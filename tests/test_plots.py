"""Issue 16 bug 8: the run figure and the env's dashboard show the applied current on a linear axis with its
limit and a min/max envelope per sample interval (no aliased switching), and the raw reference r next to y_d."""

import numpy as np
import pytest

from ehss_gym import Scenario, simulate
from ehss_gym.envs import EHSSTrackingEnv
from ehss_gym.envs.render import dashboard_figure
from ehss_gym.plotting import plot_trajectory, trajectory_figure

CHATTER = dict(sigma=1.0, current_limit=10.0, control_period=5e-5, substeps=1, t_end=0.5, friction=((1.8, 0.2, 0.3),))


def test_the_log_carries_the_exact_current_envelope_of_each_interval():
    """Against the same run logged at every control period (an independent reduction in numpy)."""
    coarse = simulate(Scenario(**CHATTER, log_interval=1e-3))
    fine = simulate(Scenario(**CHATTER, log_interval=5e-5))
    per = 20  # control periods per coarse sample
    u = fine.u_applied
    n = len(coarse.t)
    blocks = u[: n * per].reshape(n, per)
    np.testing.assert_array_equal(coarse.u_applied_min, blocks.min(axis=1))
    np.testing.assert_array_equal(coarse.u_applied_max, blocks.max(axis=1))
    np.testing.assert_array_equal(coarse.u_applied, blocks[:, 0])  # the sample itself is the first period's
    # the plain law chatters: within an interval the current swings far more than the samples show
    assert np.mean(coarse.u_applied_max - coarse.u_applied_min) > 10.0  # sigma = 1: a relay on +-10 mA


def _lines(ax):
    return {ln.get_label(): ln for ln in ax.get_lines()}


def test_run_figure_shows_the_applied_current_linearly_with_its_limit_and_r():
    """Before: a log axis scaled to the unclipped base-law spikes, no limit, no raw reference."""
    traj = simulate(Scenario(**CHATTER))
    fig = trajectory_figure(traj)
    ax_ref, _, ax_u, _ = fig.axes
    assert ax_u.get_yscale() == "linear"
    lo, hi = ax_u.get_ylim()
    assert -11.6 < lo < -10.0 and 10.0 < hi < 11.6  # the +-10 mA limit fills the panel
    limit_lines = [ln for ln in ax_u.get_lines() if ln.get_linestyle() == "--"]
    assert sorted(float(ln.get_ydata()[0]) for ln in limit_lines) == [-10.0, 10.0]
    assert ax_u.collections, "no min/max envelope drawn"
    assert "reference r (raw)" in _lines(ax_ref) and "$y_d$ (reference model)" in _lines(ax_ref)
    np.testing.assert_array_equal(_lines(ax_ref)["reference r (raw)"].get_ydata(), traj.r)


def test_plot_trajectory_writes_a_png(tmp_path):
    path = plot_trajectory(simulate(Scenario(**CHATTER)), tmp_path / "run.png", made_by="test")
    assert (tmp_path / "run.png").stat().st_size > 10_000 and path.endswith("run.png")


def test_env_dashboard_shows_the_envelope_the_limit_and_r():
    env = EHSSTrackingEnv(render_mode="rgb_array", sigma=1.0, smoothing=0.0, episode_seconds=0.2)
    env.reset(seed=0, options={"scenario": "paper"})
    for _ in range(400):
        env.step(np.zeros(1, dtype=np.float32))
    img = env.render()
    assert img.ndim == 3 and img.dtype == np.uint8
    rows = np.array(env._hist)
    u, lo, hi = rows[:, 4], rows[:, 9], rows[:, 10]
    assert np.all(lo <= u) and np.all(u <= hi) and np.all(np.abs(hi) <= 10.0 + 1e-9)
    assert np.mean(hi - lo) > 1.0  # the plain law switches within agent steps
    from ehss_gym.envs.env import HIST_COLUMNS

    fig = dashboard_figure(dict(zip(HIST_COLUMNS, rows.T)), env.config, env.scenario)
    ax_ref, _, ax_u, _ = fig.axes
    assert ax_u.get_yscale() == "linear" and ax_u.get_ylim()[1] == pytest.approx(11.5)
    assert "reference r (raw)" in _lines(ax_ref)
    assert max(abs(rows[:, 5])) > 100.0  # the base law's command spikes: off the panel, named in its title
    assert "base-law command peak" in ax_u.get_title(loc="left")


def test_env_envelope_matches_the_simulator_at_full_rate():
    """The env's per-step envelope equals the min/max of the simulator's full-rate log over the step's periods."""
    env = EHSSTrackingEnv(render_mode="rgb_array", smoothing=0.0)
    sc = env.unwrapped.scenario_template.replace(t_end=0.05, friction=(), log_interval=env.config.control_period)
    env.reset(options={"scenario": sc})
    done = False
    while not done:
        _, _, term, trunc, _ = env.step(np.zeros(1, dtype=np.float32))
        done = term or trunc
    rows = np.array(env._hist)[1:]  # after the reset row
    u = simulate(sc).u_applied
    per = env.config.agent_period
    blocks = u[: len(rows) * per].reshape(len(rows), per)
    np.testing.assert_allclose(rows[:, 9], blocks.min(axis=1), rtol=0, atol=1e-9)
    np.testing.assert_allclose(rows[:, 10], blocks.max(axis=1), rtol=0, atol=1e-9)
