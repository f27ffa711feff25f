"""The physical bound of a step (ehss_gym.study.bound): its kernels against the simulator's, its optimiser against
a closed-form optimum, and the bound against a causal policy (the env's default law) on the same steps."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ehss_gym.core.params import PlantParams
from ehss_gym.core.physics import N_LANE_CONST, integrate_lanes, lane_constants, plant_only_arrays, plant_rhs
from ehss_gym.core.signals import step
from ehss_gym.core.sim import simulate
from ehss_gym.envs import EnvConfig
from ehss_gym.study import bound, bound_kernels

pytestmark = pytest.mark.xdist_group("bound")  # one worker: the bounds' cache and compiled kernels are shared

DT = bound.SIM_STEP
# one start, few programs and a fixed window (the first the default would try, no doubling): still an admissible
# profile, so still an upper estimate of the minimum
QUICK = {"starts": ("zero",), "max_iter": 10}
WINDOW = {("velocity", 0.2): 0.0108, ("velocity", 1.0): 0.0196, ("position", 0.2): 0.1, ("position", 1.0): 0.208}


@pytest.mark.parametrize("kwargs, name", [
    ({"task": "speed"}, "task"),
    ({"amplitude": 0.0}, "amplitude"),
    ({"amplitude": math.nan}, "amplitude"),
    ({"t_step": -0.1}, "t_step"),
    ({"t_end": 0.05}, "t_end"),
    ({"current_limit": 0.0}, "current_limit"),
    ({"grid": 1.5e-4}, "grid"),  # 3 integrator steps: not an even multiple
    ({"dt": 0.0}, "dt"),
    ({"window": 5.0}, "window"),
    ({"starts": ("bang-hold", "nonsense")}, "starts"),
    ({"starts": ()}, "starts"),
    ({"seed": -1}, "seed"),
    ({"max_iter": 0}, "max_iter"),
    ({"plant": {"J": 0.05}}, "plant"),
    ({"friction": ((1.0, 0.5, 0.2),)}, "friction"),
    ({"amplitude": 500.0}, "amplitude"),  # a velocity the current limit cannot hold
])
def test_bad_arguments_name_the_parameter(kwargs, name):
    args = {"task": "velocity", "amplitude": 1.0, "t_step": 0.05, "t_end": 0.5} | kwargs
    task, amplitude = args.pop("task"), args.pop("amplitude")
    with pytest.raises(ValueError, match=name):
        bound.step_bound(task, amplitude, **args)


def test_an_unreachable_target_and_a_short_horizon_are_refused():
    with pytest.raises(ValueError, match="not reached within"):
        bound.step_bound("position", 50.0, t_step=0.0, t_end=0.2)
    with pytest.raises(ValueError, match="t_end must leave room"):
        bound.step_bound("position", 1.0, t_step=0.0, t_end=0.1, starts=("zero",))


def test_forward_pass_is_the_simulators_integrator_bit_for_bit():
    """Full-open currents that drive the relief valve, random ones, and a friction event switching on and off."""
    plant = PlantParams()
    model = bound.plant_model("velocity", plant)
    events = ((1.8, 0.004, 0.031),)
    n, spc = 1400, 4
    amps = bound._amplitudes(events, 0.0, DT, n)
    pr = bound.make_problem(model, target=1.0, limit=10.0, u_hold=0.3, dt=DT, spc=spc, n_ctrl=300, n_steps=n,
                        amps=amps)
    u = np.concatenate([np.full(150, 10.0), np.full(100, -10.0), np.random.default_rng(3).uniform(-10, 10, 50)])
    X = pr.simulate(u)
    x, work = np.zeros((4, 1)), np.zeros((6, 4, 1))  # the loop's integrator on one lane
    c = np.zeros((N_LANE_CONST, 1))
    lane_constants(plant.as_array().reshape(1, -1), c)
    ev = np.array(events, dtype=np.float64).reshape(1, -1, 3)
    arrays = plant_only_arrays(1)
    for s in range(n):
        u_s = u[s // spc] if s < 300 * spc else 0.3
        integrate_lanes(x, np.array([u_s]), np.array([s * DT]), DT, 1, c, ev, work, False, *arrays)
        assert np.array_equal(x[:, 0], X[s + 1]), f"step {s}"
    assert np.abs(X[:, 2]).max() == plant.P_s  # the relief valve acted


def test_jacobian_matches_central_differences_of_the_physics():
    p = PlantParams().as_array()
    rng = np.random.default_rng(0)
    for _ in range(20):
        x = np.array([0.3, rng.normal() * 5.0, rng.uniform(-8e6, 8e6), rng.normal() * 3e-6])
        u, a = rng.uniform(-10, 10), rng.uniform(0.0, 2.0)
        A, b = np.zeros((4, 4)), np.zeros(4)
        bound_kernels.ehss_jacobian(x, u, a, p, A, b)
        for j, scale in enumerate((1e-3, 1e-3, 1e3, 1e-9)):
            h = 1e-4 * max(abs(x[j]), scale)
            hi, lo, d1, d2 = x.copy(), x.copy(), np.zeros(4), np.zeros(4)
            hi[j] += h
            lo[j] -= h
            plant_rhs(hi, u, a * hi[1] / math.sqrt(hi[1] ** 2 + p[12]), p, d1)
            plant_rhs(lo, u, a * lo[1] / math.sqrt(lo[1] ** 2 + p[12]), p, d2)
            fd = (d1 - d2) / (2 * h)
            assert np.all(np.abs(A[:, j] - fd) <= 1e-5 * np.abs(fd) + 1e-7 * np.abs(A).max(axis=1)), (j, A[:, j], fd)
        d1, d2 = np.zeros(4), np.zeros(4)
        plant_rhs(x, u + 1e-3, a * x[1] / math.sqrt(x[1] ** 2 + p[12]), p, d1)
        plant_rhs(x, u - 1e-3, a * x[1] / math.sqrt(x[1] ** 2 + p[12]), p, d2)
        np.testing.assert_allclose(b, (d1 - d2) / 2e-3, rtol=1e-9)


@pytest.mark.parametrize("task", ["velocity", "position"])
def test_sensitivities_match_finite_differences(task):
    """Through the relief valve's clipping too (30 ms full open, then full reverse, saturate the pressure)."""
    model = bound.plant_model(task, PlantParams())
    pr = bound.make_problem(model, target=1.0, limit=10.0, u_hold=0.05, dt=DT, spc=8, n_ctrl=175, n_steps=1600)
    u = np.concatenate([np.full(75, 10.0), np.full(50, -10.0), np.random.default_rng(1).uniform(-10, 10, 50)])
    X, S = pr.sensitivity(u)
    assert np.abs(X[:, 2]).max() == PlantParams().P_s
    for j in (0, 40, 100, 130, 174):
        h = 1e-6
        up, um = u.copy(), u.copy()
        up[j] += h
        um[j] -= h
        fd = (pr.simulate(up)[pr.rows, model.out] - pr.simulate(um)[pr.rows, model.out]) / (2 * h)
        assert np.max(np.abs(fd - S[:, j])) <= 1e-5 * np.max(np.abs(S)), j  # FD's own error, at the scale of S


def _lag_optimum(spc: int):
    """The lag y' = (k u - y)/T driven from 0 to A = k U / 2 under |u| <= U: pointwise, no profile is above the
    full-on response until it reaches A (comparison principle), and holding u = A/k keeps y = A after, so the
    optimum is u = U until t* = T ln(kU / (kU - A)), then A/k; IAE* = T A - (kU - A) t*."""
    k, T, U, A = 2.0, 0.01, 10.0, 10.0
    model = bound.lag_model(k, T)
    pr = bound.make_problem(model, target=A, limit=U, u_hold=A / k, dt=DT, spc=spc, n_ctrl=(800 // spc), n_steps=1200)
    t_star = T * math.log(k * U / (k * U - A))
    return pr, t_star, T * A - (k * U - A) * t_star, A / k


def test_optimiser_finds_the_closed_form_optimum_of_a_lag():
    errors = []
    for spc in (4, 2):
        pr, t_star, exact, hold = _lag_optimum(spc)
        sols = [bound.minimise_iae(pr, bound.start_profile(name, pr, t_star, 0)) for name in bound.START_NAMES]
        iaes = np.array([s.iae for s in sols])
        assert iaes.max() - iaes.min() <= 1e-9 * exact  # every start finds the same optimum
        errors.append((iaes.min() - exact) / exact)
        best = sols[int(np.argmin(iaes))].u
        t0 = np.arange(pr.n_ctrl) * spc * DT
        before, after = t0 + spc * DT <= t_star, t0 >= t_star
        np.testing.assert_allclose(best[before], 10.0, atol=1e-6)  # bang ...
        np.testing.assert_allclose(best[after], hold, atol=1e-6)  # ... then hold
    # a piecewise-constant grid switches only on its points: above the exact optimum, by less on a finer grid
    assert 0.0 <= errors[1] < errors[0] < 5e-4, errors


def _law_iae(task: str, amplitude: float, t_step: float, t_end: float) -> tuple[float, float]:
    """The default law's IAE against the raw reference on a step from rest, from a log at the control period;
    and its largest |y| before the step."""
    tpl = EnvConfig.from_kwargs({"task": task, "bumpless": True}).template()
    traj = simulate(tpl.replace(reference=step(amplitude, t_step), friction=(), t_end=t_end,
                                log_interval=tpl.control_period))
    assert not traj.diverged
    t, e = traj.t, np.abs(traj.y - traj.r)
    post = t >= t_step
    return float(np.trapezoid(e[post], t[post])), float(np.abs(traj.y[~post]).max())


@pytest.mark.parametrize("task", ["velocity", "position"])
@pytest.mark.parametrize("amplitude", [0.2, 1.0])
def test_no_causal_policy_beats_the_bound(task, amplitude):
    """The default law applies an admissible profile; if it beat the bound, the bound would be wrong. The bound here
    uses one start (quick), so it is higher than the default one's: the test is conservative."""
    t_step, t_end = 0.02, 0.6
    b = bound.step_bound(task, amplitude, t_step=t_step, t_end=t_end, **QUICK, window=WINDOW[task, amplitude])
    law, before = _law_iae(task, amplitude, t_step, t_end)
    assert before == 0.0  # the law holds the plant at rest until the step, as the bound assumes
    assert b.iae_bound < law
    assert b.iae_bound <= b.iae_bang_hold  # and below full-open-then-hold
    assert b.t_reach >= b.t_reach_open  # nothing reaches the target before the full-open valve does
    assert b.t_reach_open > 0.0
    # the returned profile is admissible and its IAE is what the record says
    assert np.abs(b.u).max() <= 10.0
    assert b.iae_bound == pytest.approx(bound.step_iae(b.t, b.y, amplitude, t_step), rel=1e-12)


def test_velocity_bound_gap_estimates():
    """The default settings: five starts agree, halving the grid gains little, the profile is bang-bang before
    the target, and nothing after the window matters."""
    b = bound.step_bound("velocity", 0.2, t_step=0.05, t_end=0.25)
    d = b.diagnostics
    assert d.checks() == {"starts agree": True, "grid refined": True, "bang-bang": True, "tail": True}
    assert d.n_stationary == len(bound.START_NAMES)
    assert d.stationarity < 1e-5
    assert d.saturated_share > 0.9
    assert b.iae_bound <= min(iae for _, iae, _ in d.iae_by_start)
    assert bound.step_bound("velocity", 0.2, t_step=0.05, t_end=0.25) is b  # cached


def test_bound_is_odd_in_the_amplitude():
    """The plant is odd (x -> -x, u -> -u), so a step down costs what a step up does."""
    up = bound.step_bound("velocity", 0.2, t_step=0.0, t_end=0.15, **QUICK, window=WINDOW["velocity", 0.2])
    down = bound.step_bound("velocity", -0.2, t_step=0.0, t_end=0.15, **QUICK, window=WINDOW["velocity", 0.2])
    assert down.iae_bound == pytest.approx(up.iae_bound, rel=1e-3)
    assert down.u_hold == pytest.approx(-up.u_hold, rel=1e-9)


def test_hold_current_holds_the_velocity():
    model = bound.plant_model("velocity", PlantParams())
    u = bound.hold_current("velocity", 1.0, model, 10.0)
    pr = bound.make_problem(model, target=1.0, limit=10.0, u_hold=u, dt=DT, spc=2, n_ctrl=1, n_steps=40000)
    X = pr.simulate([u])  # from rest, the held current alone settles the velocity at the target
    assert abs(X[-1, 1] - 1.0) < 1e-3 * 1.0


def test_figure_and_table(tmp_path):
    b = bound.step_bound("velocity", 0.2, t_step=0.0, t_end=0.15, **QUICK, window=WINDOW["velocity", 0.2])  # cached
    law = bound.law_step("velocity", 0.2, t_step=0.0, t_end=0.15)
    path = b.plot(tmp_path / "bound.png", law=law, made_by="test")
    assert (tmp_path / "bound.png").stat().st_size > 10_000 and path.endswith("bound.png")
    row = bound.bound_row(b, law)
    assert set(row) == set(bound.TABLE_FIELDS)
    assert row["ratio"] == pytest.approx(row["iae_law"] / b.iae_bound) and row["ratio"] > 1.0


@pytest.mark.slow
@pytest.mark.parametrize("task", ["velocity", "position"])
@pytest.mark.parametrize("amplitude", [0.2, 1.5])
def test_default_bound_gap_estimates_and_law(task, amplitude):
    """The bound at its defaults, every gap estimate within its tolerance, below the law."""
    b = bound.step_bound(task, amplitude, t_step=0.05, t_end=1.0)
    assert all(b.diagnostics.checks().values()), b.diagnostics
    assert b.iae_bound < _law_iae(task, amplitude, 0.05, 1.0)[0]


@pytest.mark.slow
def test_command_writes_table_and_figures(tmp_path, capsys):
    assert bound.main(["--out", str(tmp_path), "--tasks", "velocity", "--amplitudes", "0.5"]) == 0
    assert (tmp_path / "bound.csv").read_text().startswith("task,amplitude")
    assert (tmp_path / "bound_velocity.png").exists()
    assert "| velocity |" in capsys.readouterr().out
