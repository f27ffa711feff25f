"""Issue 16 feature 10: references from an array or a Python function (simulate and simulate_batch)."""

import math

import numpy as np
import pytest

import ehss_gym as eg
from ehss_gym.envs import EHSSTrackingEnv

SC = eg.Scenario(sigma=1e5, current_limit=10.0, control_period=5e-5, substeps=1, t_end=1.0)


def test_a_sampled_sine_runs_like_the_sine():
    """Linear interpolation of 0.1 ms samples changes r by < 1e-8, so the runs agree to that order."""
    t = np.arange(0.0, 1.0 + 1e-9, 1e-4)
    table = eg.from_array(t, np.sin(2.0 * t))
    ts = np.linspace(0, 1, 777)
    np.testing.assert_allclose(table(ts), np.sin(2 * ts), atol=1.5e-9)
    a, b = eg.simulate_batch([SC, SC.replace(reference=table)])  # one batch, rows of different lengths
    np.testing.assert_allclose(b.y, a.y, atol=1e-7)
    assert b.metrics()["rmse"] == pytest.approx(a.metrics()["rmse"], rel=1e-3)


def test_values_outside_the_samples_are_held():
    ref = eg.from_array([1.0, 2.0], [3.0, 5.0])
    np.testing.assert_allclose(ref([0.0, 1.0, 1.5, 2.0, 9.0]), [3.0, 3.0, 4.0, 5.0, 5.0])
    assert ref.amplitude == 1.0 and ref.family == "table"


def test_from_function_takes_vectorised_and_scalar_functions():
    vec = eg.from_function(lambda t: np.cos(3 * t), 0.5, dt=1e-3)
    scalar = eg.from_function(lambda t: math.cos(3 * t), 0.5, dt=1e-3)
    np.testing.assert_array_equal(vec.spec, scalar.spec)
    assert vec(0.2345) == pytest.approx(math.cos(3 * 0.2345), abs=5e-6)


@pytest.mark.parametrize("t,v,needle", [
    ([0.0], [1.0], "t must hold 2 to"),
    ([0.0, 1.0], [1.0], "values must have one entry per sample time"),
    ([0.0, 0.0], [1.0, 2.0], "strictly increasing"),
    ([0.0, 1.0], [1.0, math.nan], "values must be finite"),
])
def test_bad_tables_name_the_problem(t, v, needle):
    with pytest.raises(ValueError, match=needle):
        eg.from_array(t, v)


def test_from_function_validates_its_grid():
    with pytest.raises(ValueError, match=r"dt must be in \(0, 1\]"):
        eg.from_function(np.sin, 1.0, dt=2.0)
    with pytest.raises(ValueError, match="raise dt"):
        eg.from_function(np.sin, 1e3, dt=1e-4)


def test_the_env_refuses_a_table_reference_clearly():
    env = EHSSTrackingEnv()
    sc = env.unwrapped.scenario_template.replace(reference=eg.from_array([0.0, 1.0], [0.0, 1.0]), t_end=1.0)
    with pytest.raises(ValueError, match="the env runs the parametric references.*simulate it with"):
        env.reset(options={"scenario": sc})
