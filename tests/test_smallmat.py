"""The fixed-order small-matrix exponential and product (``ehss_gym.core.smallmat``) against references computed
another way: mpmath's expm at 50 digits, SciPy's ``expm`` (LAPACK and BLAS, its own scaling choice), closed forms,
and exact rational sums."""

from __future__ import annotations

import math
from fractions import Fraction

import mpmath
import numpy as np
import pytest
import scipy.linalg
from hypothesis import given, settings
from hypothesis import strategies as st

from ehss_gym.core import filters, smallmat


def test_closed_forms():
    """A diagonal matrix, a Jordan block and a rotation generator: e^A written out by hand."""
    np.testing.assert_allclose(smallmat.expm(np.diag([-3.0, 0.5, 2.0])), np.diag(np.exp([-3.0, 0.5, 2.0])),
                               rtol=2e-15)
    a, t = -1.7, 0.9
    jordan = smallmat.expm([[a * t, t], [0.0, a * t]])  # e^{(aI + N) t} = e^{at} (I + N t)
    np.testing.assert_allclose(jordan, math.exp(a * t) * np.array([[1.0, t], [0.0, 1.0]]), rtol=2e-15, atol=1e-300)
    w = 40.0  # a norm far above the Pade approximant's range: six squarings
    rot = smallmat.expm([[0.0, w], [-w, 0.0]])
    np.testing.assert_allclose(rot, [[math.cos(w), math.sin(w)], [-math.sin(w), math.cos(w)]], atol=1e-13)


@settings(max_examples=40, deadline=None)
@given(n=st.integers(1, 8), seed=st.integers(0, 2**32 - 1), scale=st.floats(1e-3, 30.0))
def test_expm_is_accurate_against_a_50_digit_reference(n, seed, scale):
    """Random matrices of every accepted size, 1-norms from 1e-3 to ~100, against mpmath's expm at 50 digits: the
    largest error within 100 eps ||A||_1 of the result's largest entry, the normwise bound of scaling and squaring
    (each squaring doubles a relative error). Measured on 1,500 such matrices: 26 eps ||A||_1 at most; SciPy's expm
    514 eps ||A||_1, which is why SciPy is not the reference here. A wrong Pade coefficient or a squaring too few
    misses by orders of magnitude more."""
    a = np.random.default_rng(seed).standard_normal((n, n)) * scale / math.sqrt(n)
    with mpmath.workdps(50):
        ref = np.array(mpmath.expm(mpmath.matrix(a.tolist())).tolist(), dtype=np.float64)
    bound = 100 * np.finfo(np.float64).eps * max(1.0, np.linalg.norm(a, 1))
    assert np.max(np.abs(smallmat.expm(a) - ref)) <= bound * np.max(np.abs(ref))


@pytest.mark.parametrize("order,cutoff,h", [(1, 5.0, 1e-3), (2, 25.0, 1e-3), (3, 35.0, 1e-4), (4, 100.0, 1e-3),
                                            (4, 2000.0, 1e-4)])
def test_the_filters_hold_integrals_agree_with_scipy(order, cutoff, h):
    """The loop's use: the augmented matrix of a Butterworth companion form (entries up to omega_c^4 ~ 2.5e17)."""
    A, b = filters.companion(filters.butterworth_coefficients(order, cutoff))
    n = len(A)
    M = np.zeros((n + 2, n + 2))
    M[:n, :n], M[:n, n:n + 1], M[n, n + 1] = A * h, b.reshape(n, 1) * h, 1.0
    ref = scipy.linalg.expm(M)
    np.testing.assert_allclose(smallmat.expm(M), ref, rtol=1e-11, atol=1e-13 * np.max(np.abs(ref)))


def test_butterworth_coefficients_match_the_poles():
    """The closed forms against the poles multiplied out (numpy's poly), every order the loop uses."""
    for m in range(1, 5):
        wc = 2.0 * math.pi * 17.0
        poles = wc * -np.exp(1j * np.pi * np.arange(-m + 1, m, 2) / (2 * m))
        expected = np.poly(poles).real[::-1][:m]
        np.testing.assert_allclose(filters.butterworth_coefficients(m, 17.0), expected, rtol=1e-14)
    with pytest.raises(ValueError, match="order must be an integer from 1 to 4"):
        filters.butterworth_coefficients(5, 10.0)


def test_matmul_is_the_sum_in_index_order():
    """Each entry is the left-to-right sum of the products, each rounded: exactly what Fraction arithmetic rounded
    after every step gives, whatever BLAS would do."""
    rng = np.random.default_rng(3)
    a, b = rng.standard_normal((5, 4)).tolist(), rng.standard_normal((4, 3)).tolist()
    out = smallmat.matmul(a, b)
    for i in range(5):
        for j in range(3):
            acc = 0.0
            for k in range(4):
                acc = float(Fraction(acc) + Fraction(float(Fraction(a[i][k]) * Fraction(b[k][j]))))
            assert out[i][j] == acc


@pytest.mark.parametrize("bad,match", [(np.zeros((2, 3)), "square matrix of size 1 to 8"),
                                       (np.zeros((9, 9)), "square matrix of size 1 to 8"),
                                       ([[math.nan]], "must be finite")])
def test_bad_matrices_are_refused(bad, match):
    with pytest.raises(ValueError, match=match):
        smallmat.expm(bad)
