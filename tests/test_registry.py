"""The extension points are tables (ehss_gym.core.registry): a law is its kernel and one row, and runs everywhere.

The pointwise min-norm law was added as the example: its kernel in core/laws.py and its row in LAWS, nothing else.
"""

import math
import pathlib

import gymnasium as gym
import numpy as np
import pytest

from ehss_gym.controllers import parse_scripted
from ehss_gym.core import laws, references
from ehss_gym.core.registry import ESTIMATORS, LAWS, REFERENCE_FAMILIES, code, names
from ehss_gym.core.settings import LOOP_SETTINGS, Scenario
from ehss_gym.core.signals import chirp, from_array, multisine, sine, step
from ehss_gym.core.sim import simulate
from ehss_gym.envs.config import EnvConfig

ROOT = pathlib.Path(__file__).resolve().parents[1]
PACKAGE = (ROOT / "ehss_gym", ROOT / "agents", ROOT / "train")


def min_norm_reference(psi, G, s, n, sigma):
    """-a/b where a > 0, else 0, for V' = a + b u with V = (s/sigma)^n / n, formed from a and b themselves."""
    p = (s / sigma) ** (n - 1)
    a = p * psi / sigma
    b = p * G / sigma
    return -a / b if a > 0 and b != 0 else 0.0, a, b


def test_min_norm_is_the_pointwise_min_norm_control():
    """The kernel (formed from psi/G and the signs) against u = -a/b from a and b themselves, and V' <= 0."""
    rng = np.random.default_rng(0)
    checked = 0
    for _ in range(3000):
        n = int(rng.choice([2, 4, 6]))
        sigma = 10.0 ** rng.uniform(-2, 2)
        s = rng.choice([-1.0, 1.0]) * 10.0 ** rng.uniform(-2, 2) * sigma
        psi = rng.normal() * 10.0 ** rng.uniform(-3, 3)
        G = rng.choice([-1.0, 1.0]) * 10.0 ** rng.uniform(-3, 3)
        u = laws.min_norm(psi, G, s)
        want, a, b = min_norm_reference(psi, G, s, n, sigma)
        assert u == pytest.approx(want, rel=1e-12, abs=0.0)
        assert a + b * u <= 1e-9 * abs(a)  # V' <= 0: 0 where a > 0, a itself elsewhere
        checked += a > 0
    assert 1000 < checked < 2000  # both branches were exercised
    assert laws.min_norm(1.0, 0.0, 1.0) == 0.0 and laws.min_norm(1.0, 2.0, 0.0) == 0.0


def test_a_law_added_through_its_row_runs_in_simulate_and_the_env():
    """The row makes the name valid everywhere: Scenario, the env, the scripted policies; both loops run it."""
    assert "min-norm" in names(LAWS)
    for task in ("velocity", "position"):
        sc = EnvConfig.from_kwargs({"task": task, "law": "min-norm"}).template().replace(t_end=0.5)
        m = simulate(sc).metrics()
        assert not m["diverged"] and math.isfinite(m["rmse"]), task
    env = gym.make("EHSSTracking-v0", law="min-norm").unwrapped
    env.reset(seed=0)
    for _ in range(20):
        _, reward, terminated, _, info = env.step(np.zeros(1, dtype=np.float32))
        assert math.isfinite(reward) and math.isfinite(info["u_base"]) and not terminated
    assert parse_scripted("min-norm-eso-n4") == {"n": 4, "mode": "residual", "law": "min-norm", "estimator": "eso"}


def test_the_law_lives_in_its_kernel_and_its_row_only():
    """Adding a law touches two files of the package: its kernel and its table row."""
    found = sorted(str(p.relative_to(ROOT)) for folder in PACKAGE for p in folder.rglob("*.py")
                   if "min_norm" in p.read_text(encoding="utf-8") or "min-norm" in p.read_text(encoding="utf-8"))
    assert found == ["ehss_gym/core/laws.py", "ehss_gym/core/registry.py"]


def test_the_law_dispatch_calls_the_kernel_of_each_row():
    rng = np.random.default_rng(1)
    for i, row in enumerate(LAWS):
        kernel = getattr(laws, row.kernel)
        params = list(kernel.py_func.__code__.co_varnames[:kernel.py_func.__code__.co_argcount])
        for _ in range(50):
            args = {"psi": rng.normal() * 100, "G": rng.normal(), "s": rng.normal(), "n": 2.0 * rng.integers(1, 4),
                    "sigma": 10.0 ** rng.uniform(-1, 1), "smoothing": abs(rng.normal()), "ulim": 10.0}
            got = laws.base_current(i, *args.values())
            assert got == kernel(*(args[p] for p in params)), row.name
    assert math.isnan(laws.base_current(len(LAWS), 1.0, 1.0, 1.0, 2.0, 1.0, 0.0, 10.0))


def test_the_reference_dispatch_calls_the_kernel_of_each_family():
    """Each family's row evaluates through its own kernel; every family of the table has a builder."""
    refs = {"sine": sine(0.7, 3.0, 0.2, 0.1), "step": step(0.5, 0.3, -0.2), "chirp": chirp(0.8, 1.0, 9.0, 0.1, 1.0),
            "multisine": multisine([0.3, 0.2], [2.0, 9.0], None, 0.05),
            "table": from_array([0.0, 0.5, 1.0], [0.0, 1.0, -1.0])}
    assert sorted(refs) == sorted(names(REFERENCE_FAMILIES))
    for row in REFERENCE_FAMILIES:
        spec = refs[row.name].spec
        assert int(spec[0]) == code(REFERENCE_FAMILIES, row.name)
        kernel = getattr(references, row.kernel)
        for t in np.linspace(0.0, 1.2, 13):
            assert references.reference_value(t, spec) == kernel(t, spec, spec[1]), (row.name, t)


def test_estimator_rows_name_existing_kernels_and_schemes():
    from ehss_gym.core import estimators
    from ehss_gym.core.filters import SCHEMES

    for row in ESTIMATORS:
        assert callable(getattr(estimators, row.sense))
        assert row.advance is None or callable(getattr(estimators, row.advance))
        assert row.svf in SCHEMES
        assert not (row.analog and row.advance), "an analog estimator is advanced by the plant's integrator"


def test_the_loop_settings_are_the_scenario_fields_but_the_physical_ones():
    assert "law" in LOOP_SETTINGS and "estimator" in LOOP_SETTINGS and "reference" not in LOOP_SETTINGS
    with pytest.raises(ValueError, match="law must be one of"):
        Scenario(law="no-such-law")
    with pytest.raises(ValueError, match="current_limit"):
        Scenario(law="lin-sontag")  # the row's validation: this law needs a finite limit
