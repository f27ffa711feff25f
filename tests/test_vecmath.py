"""The block logarithm against libm (a different implementation): its accuracy bound, and the observation's squash
rounded to float32 equal to libm's bit for bit, over the whole float64 range and at the edges of its range reduction."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from ehss_gym.core.vecmath import CERTAIN, LOG1P_REL_ERROR, log1p_block, symlog_block


def _edges() -> np.ndarray:
    """Values where the range reduction and Kahan's factor change branch: 0, subnormals, around 2^-53 (1 + a rounds
    to 1), around sqrt(2) - 1 and every power of two (k and f switch), and the largest doubles."""
    out = [0.0, 5e-324, 1e-310, 2.0**-1022, 1e-300, 1e-30, 2.0**-54, 2.0**-53, 2.0**-52, 1e-8, 0.5,
           math.sqrt(2.0) - 1.0, 1.0, 2.0, 10.0, 22025.0, 1e15, 2.0**53, 1e300, np.finfo(np.float64).max]
    for e in range(-60, 1024, 7):
        for m in (1.0, math.sqrt(2.0), 1.5):
            x = m * 2.0**e
            if math.isfinite(x):
                out += [np.nextafter(x, 0.0), x, np.nextafter(x, np.inf)]
    return np.array([x for x in out if math.isfinite(x)])


def _sample(n: int, seed: int) -> np.ndarray:
    """Log-uniform values over 1e-320..1e308 plus the edges."""
    rng = np.random.default_rng(seed)
    return np.concatenate([10.0 ** rng.uniform(-320.0, 308.0, n), rng.uniform(0.0, 30.0, n), _edges()])


def _log1p(a: np.ndarray) -> np.ndarray:
    y = np.empty_like(a)
    log1p_block(a, y, np.empty((3, len(a))))
    return y


def test_log1p_block_is_within_its_stated_relative_error_of_libm():
    a = _sample(200_000, 0)
    ref = np.array([math.log1p(x) for x in a])
    got = _log1p(a)
    rel = np.abs(got - ref) / np.where(ref > 0.0, ref, 1.0)
    # libm's own error is below an ulp (2^-52 relative), so the sum bounds ours against the true value
    assert rel.max() < LOG1P_REL_ERROR, (a[rel.argmax()], rel.max())
    assert np.all(got[a == 0.0] == 0.0)
    assert CERTAIN > 16.0 * (LOG1P_REL_ERROR + 2.0**-52)


def _symlog32(v: np.ndarray) -> np.ndarray:
    y = np.empty_like(v)
    symlog_block(v, y, np.empty((4, len(v))))
    return y.astype(np.float32)


def test_symlog_block_rounds_to_libms_float32_bit_for_bit():
    a = _sample(200_000, 1)
    v = np.concatenate([a, -a, [-0.0]])
    ref = np.array([math.copysign(math.log1p(abs(x)), x) for x in v]).astype(np.float32)
    got = _symlog32(v)
    assert got.tobytes() == ref.tobytes()


@settings(max_examples=300, deadline=None)
@given(st.lists(st.floats(allow_nan=False, allow_infinity=False), min_size=1, max_size=40))
def test_symlog_block_equals_libm_on_any_finite_block(values):
    v = np.array(values, dtype=np.float64)
    ref = np.array([math.copysign(math.log1p(abs(x)), x) for x in v]).astype(np.float32)
    assert _symlog32(v).tobytes() == ref.tobytes()
