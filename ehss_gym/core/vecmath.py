"""Math over whole blocks of lanes, where libm's scalar calls would stop the compiler from vectorising a loop.

:func:`symlog_block` is the observation's squash, sign(v) log(1 + |v|), for the float32 observation: a logarithm
written as plain arithmetic (no libm call, so a loop over lanes vectorises), accurate to within
:data:`LOG1P_REL_ERROR` of the true value, and a check that the float32 rounding of the result cannot differ from
that of libm's ``log1p``: where the true value could lie on either side of a float32 rounding boundary, the lane
falls back to libm. The float32 result is therefore libm's, bit for bit (``tests/test_vecmath.py`` checks both claims
against libm over the whole float64 range).

:func:`normal_block` is the sensor noise's Box-Muller sample, sqrt(-2 log u1) cos(2 pi u2), as polynomials over the
block (a loop that vectorises), within :data:`NORMAL_REL` of libm's value relative to it. It is an estimate: the
sensors use it only where every value within that bound of it gives the same measured state, and take libm's
otherwise, so the measurement is libm's bit for bit (:func:`ehss_gym.core.controller.sense_lanes`).
"""

from __future__ import annotations

import math
from decimal import Decimal, localcontext

import numpy as np

from .jit import jit_inline, jit_noalloc

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


@jit_inline
def _unit_bits(u, kf, f):
    """kf[i] = the exponent of u[i] and f[i] its mantissa in [1, 2), from the bits (exact; u[i] positive normal)."""
    ub = u.view(np.int64)
    fb = f.view(np.int64)
    for i in range(u.shape[0]):
        b = ub[i]
        kf[i] = float(((b >> 52) & _EXP_MASK) - 1023)
        fb[i] = (b & _FRAC_MASK) | _ONE_BITS


@jit_inline
def _log_parts(kf, f):
    """log(2^kf f) for f in [1, 2) (from :func:`_unit_bits`) as plain arithmetic: reduced to k log 2 + log x, x in
    [sqrt(2)/2, sqrt(2)) (exact), log x = 2 atanh(s), s = (x - 1)/(x + 1), |s| < 0.172, by its series to s^25
    (truncation < 1e-20)."""
    big = f > SQRT2
    x = 0.5 * f if big else f  # exact
    k = kf + 1.0 if big else kf
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
    return k * LN2 + (two_s + two_s * z * p)


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
    for i in range(n):
        u[i] = 1.0 + a[i]
    _unit_bits(u, kf, f)
    for i in range(n):
        log_u = _log_parts(kf[i], f[i])
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
    # the check and the sign over the block first (no call in the loop, so it vectorises), then libm's result for
    # the few values whose float32 rounding the estimate cannot settle (y >= 0 before its sign: |y| is the estimate)
    unsure = 0
    for i in range(n):
        r = y[i]
        unsure += np.float32(r * (1.0 - CERTAIN)) != np.float32(r * (1.0 + CERTAIN))
        y[i] = math.copysign(r, v[i])
    if unsure > 0:
        for i in range(n):
            r = abs(y[i])
            if np.float32(r * (1.0 - CERTAIN)) != np.float32(r * (1.0 + CERTAIN)):
                y[i] = math.copysign(math.log1p(a[i]), v[i])  # the true value may round to either float32


def _pio2_parts() -> tuple[float, float, float, float]:
    """pi/2 in three parts for the cosine's range reduction (Cody and Waite), and 2/pi rounded: P1 and P2 carry 32
    and 33 bits, so q P1 and q P2 are exact for the quadrants q < 2^20 that occur, and P1 + P2 + P3 is pi/2 to within
    2^-118. Worked out in decimal arithmetic (a local context: the caller's is untouched)."""
    with localcontext() as ctx:
        ctx.prec = 60
        half_pi = Decimal("1.57079632679489661923132169163975144209858469968755291048747229615390820314310449931")
        p1 = math.ldexp(math.floor(math.ldexp(float(half_pi), 32)), -32)
        p2 = math.ldexp(math.floor(math.ldexp(float(half_pi - Decimal(p1)), 65)), -65)
        p3 = float(half_pi - Decimal(p1) - Decimal(p2))
        return p1, p2, p3, float(1 / half_pi)


# INV_PIO2 only picks the quadrant: the reduction is exact whatever it picks
PIO2_1, PIO2_2, PIO2_3, INV_PIO2 = _pio2_parts()
# Taylor coefficients of cos and sin, (-1)^k / (2k)! and (-1)^k / (2k+1)!, correctly rounded (Python's int division):
# on the reduced |r| <= pi/4 + 2^-40 the first omitted terms are below 2^-60 of the result.
_C1, _C2, _C3, _C4, _C5, _C6, _C7, _C8, _C9 = ((-1) ** k / math.factorial(2 * k) for k in range(1, 10))
_S1, _S2, _S3, _S4, _S5, _S6, _S7, _S8, _S9 = ((-1) ** k / math.factorial(2 * k + 1) for k in range(1, 10))
# Bound on |n / n_libm - 1| for normal_block's n against libm's sqrt(-2 log u1) cos(2 pi u2), u1 in (0, 1], u2 in
# [0, 1) (the uniforms of ehss_gym.core.physics.noise_uniforms). Both are within a few roundings of the true value at
# the same argument a = 2 pi u2 (the same double on both paths): libm's log and cos within 1 ulp (glibc documents
# 0.52 and 0.55), its sqrt and the product within half an ulp, so libm's n is within 5 2^-53 of it; the block's log
# (exact reduction, one division, the series' roundings, k log 2) and cosine (exact reduction but for its last
# rounding, Horner's roundings) within about 4 2^-53 each, so its n is within 8 2^-53. Together 13 2^-53 (2^-49.3),
# which tests/test_vecmath.py checks over 300,000 uniform pairs and the reductions' edges (the largest found over 4
# million pairs: 2^-50.4). NORMAL_REL, 32 2^-53, leaves a factor of 2.4 above it: a libm whose log and cos were a few
# ulps off would still lie in the bracket. A wider bound would cost speed (the sensors fall back to libm where the
# bracket straddles a rounding of the reading), not exactness.
NORMAL_REL = 2.0**-48


@jit_noalloc
def _box_muller(kf, f, u2, out):
    """out[i] = sqrt(-2 log u1) cos(2 pi u2[i]), u1 = 2^kf[i] f[i] (:func:`normal_block`); selects, no branch."""
    for i in range(f.shape[0]):
        log_u1 = _log_parts(kf[i], f[i])
        # cos a, a = 2 pi u2 as libm's caller computes it: a = q pi/2 + r, |r| <= pi/4 (+ a rounding of 2/pi);
        # a - q P1 and (a - q P1) - q P2 lose nothing where r is small (Sterbenz), so r is relatively accurate near
        # the cosine's zeros
        a = 2.0 * math.pi * u2[i]
        q = math.floor(a * INV_PIO2 + 0.5)
        r = ((a - q * PIO2_1) - q * PIO2_2) - q * PIO2_3
        r2 = r * r
        c = _C9
        c = _C8 + r2 * c
        c = _C7 + r2 * c
        c = _C6 + r2 * c
        c = _C5 + r2 * c
        c = _C4 + r2 * c
        c = _C3 + r2 * c
        c = _C2 + r2 * c
        c = _C1 + r2 * c
        cos_r = 1.0 + r2 * c
        t = _S9
        t = _S8 + r2 * t
        t = _S7 + r2 * t
        t = _S6 + r2 * t
        t = _S5 + r2 * t
        t = _S4 + r2 * t
        t = _S3 + r2 * t
        t = _S2 + r2 * t
        t = _S1 + r2 * t
        sin_r = r + r * r2 * t
        quadrant = int(q) & 3  # cos a = cos r, -sin r, -cos r, sin r
        cos_a = sin_r if quadrant & 1 == 1 else cos_r
        cos_a = -cos_a if quadrant == 1 or quadrant == 2 else cos_a
        out[i] = math.sqrt(-2.0 * log_u1) * cos_a


@jit_noalloc
def normal_block(u1, u2, out, w0, w1):
    """out[i] = sqrt(-2 log u1[i]) cos(2 pi u2[i]) within NORMAL_REL of libm's value, relative (the Box-Muller sample
    of :func:`ehss_gym.core.physics.normal_from`), for u1[i] in (0, 1] and u2[i] in [0, 1), as loops that vectorise.
    Exactly 0 where u1[i] == 1, as libm's. ``w0`` and ``w1`` are float64 scratch of len(u1) (contiguous rows, as
    every argument: a view of unknown stride would not vectorise)."""
    _unit_bits(u1, w0, w1)
    _box_muller(w0, w1, u2, out)


__all__ = ["log1p_block", "symlog_block", "normal_block", "LOG1P_REL_ERROR", "CERTAIN", "NORMAL_REL", "LN2"]
