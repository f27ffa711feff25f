"""Math over whole blocks of lanes, where libm's scalar calls would stop the compiler from vectorising a loop.

:func:`symlog_block` is the observation's squash, sign(v) log(1 + |v|), for the float32 observation: a logarithm
written as plain arithmetic (no libm call, so a loop over lanes vectorises), accurate to within
:data:`LOG1P_REL_ERROR` of the true value, and a check that the float32 rounding of the result cannot differ from
that of libm's ``log1p``: where the true value could lie on either side of a float32 rounding boundary, the lane
falls back to libm. The float32 result is therefore libm's, bit for bit (``tests/test_vecmath.py`` checks both claims
against libm over the whole float64 range).
"""

from __future__ import annotations

import math

import numpy as np

from .jit import jit_noalloc

LN2 = 0.6931471805599453  # log(2), rounded to float64
SQRT2 = 1.4142135623730951
# Bound on the relative error of log1p_block against the true log(1 + a), a >= 0: the range reduction is exact, the
# series' truncation is below 1e-20, and the few roundings (the division s = (f - 1)/(f + 1), the series, k log 2 +
# log f with its mild cancellation for f < 1, and Kahan's a / (u - 1) factor) stay within a few units of 2^-53;
# tests/test_vecmath.py measures the largest error over the float64 range, far below this bound.
LOG1P_REL_ERROR = 2.0**-46
# The float32 rounding of y is certain when y (1 - CERTAIN) and y (1 + CERTAIN) round to the same float32: the true
# value and libm's result (within an ulp of it) both lie in between. CERTAIN is far above LOG1P_REL_ERROR + 2^-52
# and far below float32's half ulp 2^-24, so about one value in 2^16 falls back to libm.
CERTAIN = 2.0**-40
_EXP_MASK = np.int64(0x7FF)
_FRAC_MASK = np.int64(0x000FFFFFFFFFFFFF)
_ONE_BITS = np.int64(0x3FF0000000000000)


@jit_noalloc
def log1p_block(a, y, w):
    """y[i] = log(1 + a[i]) for finite a[i] >= 0, as plain arithmetic over the block (loops that vectorise).

    u = 1 + a is reduced to 2^k f, f in [sqrt(2)/2, sqrt(2)), from u's bits (exponent and mantissa, exact);
    log f = 2 atanh(s), s = (f - 1)/(f + 1), |s| < 0.172, by its series to s^25 (truncation < 1e-20); Kahan's factor
    a / (u - 1) restores what rounding 1 + a lost. Relative error < LOG1P_REL_ERROR. ``w`` is float64 scratch
    (3, len(a)); each loop reads and writes distinct rows, so the bits are read through one view and written through
    another in separate loops.
    """
    n = a.shape[0]
    u, f, kf = w[0], w[1], w[2]
    ubits = u.view(np.int64)
    fbits = f.view(np.int64)
    for i in range(n):
        u[i] = 1.0 + a[i]
    for i in range(n):
        b = ubits[i]
        kf[i] = float(((b >> 52) & _EXP_MASK) - 1023)
        fbits[i] = (b & _FRAC_MASK) | _ONE_BITS  # f in [1, 2): u's mantissa
    for i in range(n):
        x = f[i]
        big = x > SQRT2
        x = 0.5 * x if big else x  # exact
        k = kf[i] + 1.0 if big else kf[i]
        s = (x - 1.0) / (x + 1.0)  # x - 1 is exact (Sterbenz)
        z = s * s
        p = 1.0 / 25.0
        p = 1.0 / 23.0 + z * p
        p = 1.0 / 21.0 + z * p
        p = 1.0 / 19.0 + z * p
        p = 1.0 / 17.0 + z * p
        p = 1.0 / 15.0 + z * p
        p = 1.0 / 13.0 + z * p
        p = 1.0 / 11.0 + z * p
        p = 1.0 / 9.0 + z * p
        p = 1.0 / 7.0 + z * p
        p = 1.0 / 5.0 + z * p
        p = 1.0 / 3.0 + z * p
        two_s = 2.0 * s
        log_u = k * LN2 + (two_s + two_s * z * p)
        d = u[i] - 1.0
        # u == 1: a < 2^-53 and log(1 + a) = a to within a^2 / 2; else Kahan's log(u) a / (u - 1)
        y[i] = a[i] if d == 0.0 else log_u * (a[i] / d)


@jit_noalloc
def symlog_block(v, y, w):
    """y[i] = sign(v[i]) log(1 + |v[i]|) for finite v, whose float32 rounding is that of libm's
    ``math.copysign(math.log1p(abs(v)), v)``, bit for bit (module docstring). ``w`` is float64 scratch
    (4, len(v))."""
    n = v.shape[0]
    a = w[3]
    for i in range(n):
        a[i] = abs(v[i])
    log1p_block(a, y, w[:3])
    for i in range(n):
        r = y[i]
        if np.float32(r * (1.0 - CERTAIN)) != np.float32(r * (1.0 + CERTAIN)):
            r = math.log1p(a[i])  # the true value may round to either float32: libm's result decides
        y[i] = math.copysign(r, v[i])


__all__ = ["log1p_block", "symlog_block", "LOG1P_REL_ERROR", "CERTAIN", "LN2"]
