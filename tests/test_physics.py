"""The plant, its Lie derivatives and the Sontag law against slow, independent references."""

import math

import mpmath
import numpy as np
import pytest
from reference import lie_reference, plant_rhs_np, sontag_reference

from ehss_gym.core.laws import sontag
from ehss_gym.core.params import PlantParams
from ehss_gym.core.physics import (
    N_LANE_CONST,
    gaussian,
    integrate_lanes,
    lane_constants,
    lie_derivatives,
    plant_only_arrays,
    plant_rhs,
)

P = PlantParams()
PA = P.as_array()


def integrate_one(x, u, t0, h, substeps, events):
    """The loop's integrator on one plant state ``x`` (in place) with the current u [mA] held over [t0, t0 + h]."""
    X = x.reshape(4, 1).copy()
    c = np.zeros((N_LANE_CONST, 1))
    lane_constants(PA.reshape(1, -1), c)
    ev = np.asarray(events, dtype=float).reshape(1, -1, 3) if len(events) else np.zeros((1, 0, 3))
    integrate_lanes(X, np.array([float(u)]), np.array([t0]), h, substeps, c, ev, np.zeros((6, 4, 1)), False,
                    *plant_only_arrays(1))
    x[:] = X[:, 0]


def admissible_states(n, seed=0):
    """Random states in the operating envelope: |x3| <= 2 P_s / 3 (the paper's servo-valve
    requirement), velocities up to 20 rad/s, valve areas up to K * 20 mA, some near x4 = 0."""
    rng = np.random.default_rng(seed)
    x = np.empty((n, 4))
    x[:, 0] = rng.uniform(-3, 3, n)
    x[:, 1] = rng.uniform(-20, 20, n)
    x[:, 2] = rng.uniform(-2 / 3, 2 / 3, n) * P.P_s
    x[:, 3] = rng.uniform(-1, 1, n) * P.K * 20 * 10.0 ** rng.uniform(-4, 0, n)  # log-spread through zero
    return x


def h_vec(x, order):
    h = np.zeros(4)
    F, G = lie_derivatives(x, PA, order, h)
    return h, F, G


@pytest.mark.parametrize("order", [3, 4])
def test_lie_derivatives_match_symbolic_derivation(order):
    worst = 0.0
    for x in admissible_states(1000, seed=order):
        h, F, G = h_vec(x, order)
        hr, Fr, Gr = lie_reference(x, P, order)
        for a, b in list(zip(h[:order], hr)) + [(F, Fr), (G, Gr)]:
            worst = max(worst, abs(a - b) / max(abs(b), 1e-300))
    assert worst < 1e-9


@pytest.mark.parametrize("order", [3, 4])
def test_lie_derivatives_match_finite_differences(order):
    """d/dt h_i along x' = f(x) + g u is h_{i+1}, and d/dt h_{m-1} is F + G u (relative error < 1e-6)."""
    rng = np.random.default_rng(10 + order)
    worst = 0.0
    for x in admissible_states(1000, seed=20 + order):
        u = rng.uniform(-10, 10)
        dx = np.zeros(4)
        plant_rhs(x, u, 0.0, PA, dx)
        h, F, G = h_vec(x, order)

        def ddt(eps, i):  # central difference of h_i along the flow
            return (h_vec(x + eps * dx, order)[0][i] - h_vec(x - eps * dx, order)[0][i]) / (2 * eps)

        eps = 1e-7
        for i in range(order):
            fd = (4 * ddt(eps / 2, i) - ddt(eps, i)) / 3  # Richardson
            exact = F + G * u if i == order - 1 else h[i + 1]
            scale = abs(F) + abs(G * u) if i == order - 1 else abs(exact)
            worst = max(worst, abs(fd - exact) / max(scale, 1e-300))
    assert worst < 1e-6


def test_input_gain_is_positive_and_matches_notes_near_rest():
    _, _, G = h_vec(np.zeros(4), 3)
    assert G > 0
    assert G == pytest.approx(3.12e6, rel=0.01)  # NOTES: g ~ 3.1e6 near x3 = 0


def test_plant_rhs_matches_plain_python():
    rng = np.random.default_rng(3)
    for x in admissible_states(200, seed=3):
        u = rng.uniform(-10, 10)
        dx = np.zeros(4)
        tf = 1.8 * x[1] / math.sqrt(x[1] ** 2 + P.delta_friction)
        plant_rhs(x, u, tf, PA, dx)
        ref = plant_rhs_np(0.5, x, u, P, ((1.8, 0.0, 1.0),))
        np.testing.assert_allclose(dx, ref, rtol=1e-12, atol=1e-30)


def test_rest_is_an_equilibrium_with_zero_current():
    x = np.zeros(4)
    for k in range(1000):
        integrate_one(x, 0.0, k * 1e-4, 1e-4, 10, ())
    assert np.all(x == 0.0)


def test_orifice_never_nan_even_beyond_supply_pressure():
    """sign(dp)*sqrt(|dp|) regularised: flow reverses smoothly when |x3| > P_s, no NaN."""
    dx = np.zeros(4)
    for x3 in (-3 * P.P_s, -P.P_s, 0.0, P.P_s, 1.0001 * P.P_s, 3 * P.P_s):
        for x4 in (-1e-5, -1e-12, 0.0, 1e-12, 1e-5):
            plant_rhs(np.array([0.0, 0.0, x3, x4]), 1.0, 0.0, PA, dx)
            assert np.all(np.isfinite(dx))
    # beyond supply pressure with the valve open to it, flow reverses and pushes x3 back down
    plant_rhs(np.array([0.0, 0.0, 1.5 * P.P_s, 1e-6]), 0.0, 0.0, PA, dx)
    assert dx[2] < 0


def test_pressure_stays_within_supply_under_bang_bang_current():
    rng = np.random.default_rng(5)
    x = np.zeros(4)
    peak = 0.0
    u = 10.0
    for k in range(20000):  # 2 s of random +-10 mA switching every 1 ms
        if k % 10 == 0:
            u = 10.0 * np.sign(rng.standard_normal())
        integrate_one(x, u, k * 1e-4, 1e-4, 10, ())
        peak = max(peak, abs(x[2]))
    assert peak <= P.P_s


def test_lanes_integrated_together_equal_each_lane_alone():
    """Lanes share the integrator's loops (vectorised over lanes), never their values: B lanes advanced together
    give, bit for bit, what each gives alone."""
    rng = np.random.default_rng(7)
    B = 5
    X = admissible_states(B, seed=7).T.copy()
    x_alone = X.T.copy()
    U = rng.uniform(-10, 10, B)
    events = np.tile(np.array([[1.8, 0.00025, 0.0007]]), (B, 1, 1))
    c = np.zeros((N_LANE_CONST, B))
    lane_constants(np.tile(PA, (B, 1)), c)
    for k in range(10):
        integrate_lanes(X, U, np.full(B, k * 1e-4), 1e-4, 7, c, events, np.zeros((6, 4, B)), False,
                        *plant_only_arrays(B))
        for b in range(B):
            integrate_one(x_alone[b], U[b], k * 1e-4, 1e-4, 7, events[b])
    assert np.array_equal(X.T, x_alone)


# --- Sontag's formula -------------------------------------------------------


@pytest.mark.parametrize("n", [2, 4, 6])
def test_sontag_matches_textbook_form_and_gives_its_clf_derivative(n):
    rng = np.random.default_rng(n)
    for _ in range(2000):
        psi = rng.normal() * 10.0 ** rng.uniform(-2, 6)
        G = 3e6 * rng.uniform(0.5, 1.5) * rng.choice([-1, 1])
        s = rng.normal() * 10.0 ** rng.uniform(-3, 3)
        sigma = 10.0 ** rng.uniform(-1, 3)
        u = sontag(psi, G, s, float(n), sigma, 0.0)
        assert u == pytest.approx(sontag_reference(psi, G, s, n, sigma, 0.0), rel=1e-9, abs=1e-12 * abs(psi / G))
        # V' = a + b u = -sqrt(a^2 + b^4)
        a = (s / sigma) ** (n - 1) * psi / sigma
        b = (s / sigma) ** (n - 1) * G / sigma
        assert a + b * u == pytest.approx(-math.sqrt(a * a + b**4), rel=1e-6)


def test_sontag_n6_does_not_overflow_where_the_printed_form_does():
    psi, G, s, n = 2.0e6, 3.1e6, 2.0e16, 6  # s^(4n-4) = s^20 overflows float64
    with np.errstate(all="ignore"):
        printed = -(s**5 * psi + np.sqrt(np.float64(s**5 * psi) ** 2 + np.float64(s**5 * G) ** 4)) / (s**5 * G)
    assert not np.isfinite(printed) or printed == 0.0
    u = sontag(psi, G, s, float(n), 1.0, 0.0)
    mp = mpmath.mpf
    mpmath.mp.dps = 60
    a = mp(s) ** 5 * mp(psi)
    b = mp(s) ** 5 * mp(G)
    exact = -(a + mpmath.sqrt(a**2 + b**4)) / b
    assert math.isfinite(u)
    assert u == pytest.approx(float(exact), rel=1e-12)


def test_sontag_special_cases():
    assert sontag(5.0, 3e6, 0.0, 2.0, 1.0, 0.0) == 0.0  # b = 0 -> u = 0 (Sontag's definition)
    assert sontag(5.0, 0.0, 1.0, 2.0, 1.0, 0.0) == 0.0  # no authority -> u = 0
    # smoothed: equivalent control at s = 0, and V' keeps its sign elsewhere
    assert sontag(6.0, 3.0, 0.0, 4.0, 1.0, 0.5) == pytest.approx(-2.0)
    for s in (-2.0, -1e-3, 1e-3, 2.0):
        u = sontag(6.0, 3.0, s, 4.0, 1.0, 0.5)
        assert s * (6.0 + 3.0 * u) < 0  # s s' < 0  =>  V decreases


def test_gaussian_noise_is_deterministic_and_standard():
    a = np.array([gaussian(11, k, 2) for k in range(50000)])
    b = np.array([gaussian(11, k, 2) for k in range(50000)])
    c = np.array([gaussian(12, k, 2) for k in range(50000)])
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
    assert abs(a.mean()) < 0.02
    assert a.std() == pytest.approx(1.0, abs=0.02)
    assert abs(np.corrcoef(a[:-1], a[1:])[0, 1]) < 0.02
