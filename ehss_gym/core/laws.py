r"""The CLF laws: the base current from the combined error s, its drift and its input gain, one kernel per law.

Derivation (docs/MODEL.md, "Laws"). With the combined error s and
s' = psi + G u, the CLF V = (s/sigma)^n / n has V' = a + b u with::

    a = (s/sigma)^(n-1) psi / sigma,    b = (s/sigma)^(n-1) G / sigma.

Sontag's universal formula u = -(a + sqrt(a^2 + b^4)) / b (u = 0 if b = 0)
gives V' = -sqrt(a^2 + b^4) < 0. Since a and b share (s/sigma)^(n-1)::

    u = -psi/G - sign(s) sign(G) hypot(psi/G, |s/sigma|^(n-1) |G| / sigma)

which never forms s^(4n-4). |s/sigma|^(n-1) is formed by repeated multiplication
(cheap, and correctly scaled whenever it is a normal float), falling back to log
space when it over- or underflows, so nothing overflows unless the current itself
does. sigma = 1 is the paper's law.

Smoothing (not in the paper; the paper's "future work" on chattering): sign(s)
is replaced by s / sqrt(s^2 + w^2), the same shape as the paper's Eq. (2)
sigmoid with delta = w^2. w = 0 is the plain law. The sign of V' is unchanged,
so V still decreases wherever s != 0, only more gently inside |s| < w; at
s = 0 the smoothed law is the equivalent control -psi/G.

Combined error, relative degree m (3 velocity, 4 position)::

    s = e^(m-1) + lambda_{m-2} e^(m-2) + ... + lambda_0 e
    psi = F - y_d^(m) + lambda_{m-2} e^(m-1) + ... + lambda_0 e'

with lambda the Butterworth coefficients of order m-1 at f_r (Table I).

A law is its kernel here and a row of :data:`ehss_gym.core.registry.LAWS` (its name, its doc, whether it needs a
current limit); :func:`base_current` calls the kernel of the law's code, with the arguments its parameters name
(``psi, G, s, n, sigma, smoothing, ulim``).
"""

from __future__ import annotations

import math

from .jit import dispatch, jit
from .registry import LAWS


@jit
def smooth_sign(s, smoothing):
    """sign(s), or s / sqrt(s^2 + w^2) with the width w = ``smoothing`` > 0 (the boundary layer)."""
    if smoothing > 0.0:
        return s / math.sqrt(s * s + smoothing * smoothing)
    if s > 0.0:
        return 1.0
    if s < 0.0:
        return -1.0
    return 0.0


@jit
def switching_gain(s, n, sigma, scale):
    """|s/sigma|^(n-1) * scale / sigma >= 0 without overflow in the intermediate power (0 at s = 0).

    |s/sigma|^(n-1) is formed by repeated multiplication (cheap, and correctly scaled whenever it is a normal
    float), falling back to log space when it over- or underflows.
    """
    if s == 0.0:
        return 0.0
    x = abs(s) / sigma
    ni = int(n)
    p = _int_power(x, ni - 1) if ni == n else 0.0  # n is an even integer (check_n); 0.0: log space
    if 1e-290 < p < math.inf:
        # p * (scale/sigma) is correctly rounded and overflows only where the result itself does
        return p * (scale / sigma)
    # |s/sigma|^(n-1) itself over- or underflows: log space keeps the product
    return math.exp((n - 1.0) * math.log(x) + math.log(scale / sigma))


@jit
def sontag(psi, G, s, n, sigma, smoothing):
    """Sontag current [mA] for s' = psi + G u and V = (s/sigma)^n / n.

    Args:
        psi: drift of s [unit of s / s].
        G: input gain of s [unit of s / s per mA].
        s: combined error.
        n: even power factor >= 2.
        sigma: CLF scale (> 0), in the unit of s.
        smoothing: width w >= 0 of the smooth sign; 0 = plain sign(s).
    """
    if G == 0.0 or not math.isfinite(G):
        return 0.0
    sg = smooth_sign(s, smoothing)
    if sg == 0.0 and smoothing == 0.0:
        return 0.0  # s = 0, b = 0: Sontag's formula gives u = 0
    ratio = psi / G
    aG = abs(G)
    beta = switching_gain(s, n, sigma, aG)
    gsign = 1.0 if G > 0.0 else -1.0
    a = abs(ratio)
    big = a if a > beta else beta
    if 1e-150 < big < 1e150:  # the squares neither over- nor underflow: sqrt is cheaper than libm's hypot
        mag = math.sqrt(ratio * ratio + beta * beta)
    else:
        mag = math.hypot(ratio, beta)
    return -ratio - sg * gsign * mag


@jit
def lin_sontag(psi, G, s, n, sigma, smoothing, ulim):
    r"""Lin-Sontag current [mA], |u| <= ``ulim``, for s' = psi + G u and V = (s/sigma)^n / n.

    Lin & Sontag (1991) for the unit ball, with v = u / U (U = ``ulim``) and V' = a + b_v v::

        v = -(a + sqrt(a^2 + b_v^4)) b_v / (b_v^2 (1 + sqrt(1 + b_v^2))),   b_v = U b.

    With a = (s/sigma)^(n-1) psi / sigma and b_v = (s/sigma)^(n-1) U G / sigma sharing (s/sigma)^(n-1)
    (docs/MODEL.md, "Laws")::

        u = -(psi/G + sg sign(G) hypot(psi/G, U beta_U)) / (1 + |sg| sqrt(1 + beta_U^2)),
        beta_U = |s/sigma|^(n-1) U |G| / sigma,

    sg = sign(s) (|sg| = 1: the formula itself) or the smooth sign of width w. Wherever |psi| < U |G| (where
    V' < 0 is possible with |u| <= U) the command is within the bound and V' < 0 for every s != 0, the
    smoothed law included; at s = 0 the smoothed law is the equivalent control -psi/G. Elsewhere the
    formula asks for more than U and the command is clipped to U in its own direction, which minimises V'.
    Evaluated on scaled quantities (by max(|psi/(G U)|, beta_U, 1)), so nothing overflows; n enters only
    through beta_U.

    Args:
        psi: drift of s [unit of s / s], as in :func:`sontag`.
        G: input gain of s [unit of s / s per mA].
        s: combined error.
        n: even power factor >= 2.
        sigma: CLF scale (> 0), in the unit of s.
        smoothing: width w >= 0 of the smooth sign; 0 = plain sign(s).
        ulim: the bound U [mA] (finite, > 0).
    """
    if G == 0.0 or not math.isfinite(G):
        return 0.0
    sg = smooth_sign(s, smoothing)
    if sg == 0.0 and smoothing == 0.0:
        return 0.0  # b = 0
    gsign = 1.0 if G > 0.0 else -1.0
    rho = psi / (G * ulim)  # the equivalent control over the bound
    sgg = sg * gsign
    if not math.isfinite(rho):  # |psi/G| far beyond the bound: the limit of the formula
        if rho != rho:
            return rho
        return -ulim * (1.0 if rho > 0.0 else -1.0) if sgg * rho > 0.0 or abs(sg) < 1.0 else 0.0
    bu = switching_gain(s, n, sigma, ulim * abs(G))
    big = max(abs(rho), bu, 1.0)
    rs = rho / big
    bs = bu / big
    ib = 1.0 / big
    hyp = math.hypot(rs, bs)
    if sgg * rs < 0.0:
        # rs + sgg hyp cancels where |rho| >> beta_U (all digits lost at |rho| ~ 1e8 beta_U): rationalised,
        # rs + sgg hyp = sign(sgg) (sg^2 bs^2 - (1 - sg^2) rs^2) / (|sgg| hyp + |rs|), 1 - sg^2 = w^2/(s^2 + w^2)
        c = 0.0
        if smoothing > 0.0:
            r = s / smoothing
            c = 1.0 / (1.0 + r * r)
        num = (sg * sg * bs * bs - c * rs * rs) / (abs(sgg) * hyp + abs(rs))
        if sgg < 0.0:
            num = -num
    else:
        num = rs + sgg * hyp
    den = ib + abs(sg) * math.hypot(ib, bs)
    v = -num / den
    if v > 1.0:
        v = 1.0
    elif v < -1.0:
        v = -1.0
    return ulim * v


@jit
def min_norm(psi, G, s):
    """Pointwise min-norm current [mA] for s' = psi + G u: u = -a/b where a > 0, else 0, for V' = a + b u.

    With a = (s/sigma)^(n-1) psi / sigma and b = (s/sigma)^(n-1) G / sigma (n even, so the power keeps the sign of
    s): a > 0 exactly where s and psi have the same sign, and there -a/b = -psi/G, the smallest current that makes
    V' <= 0 (V' = 0); elsewhere V' = a <= 0 with no current at all. Neither n nor sigma changes it.
    """
    if G == 0.0 or not math.isfinite(G):
        return 0.0
    if (s > 0.0 and psi > 0.0) or (s < 0.0 and psi < 0.0):
        return -psi / G
    return 0.0


EPS = 2.220446049250313e-16  # the float64 machine epsilon


@jit
def decrease_clip(a, b, u0, r, bound):
    r"""The residual nearest to ``r`` [mA] with which a + b (u0 + r) <= ``bound``: the Lyapunov-constrained clip.

    V' = a + b u is affine in the current u = u0 + r, so the residuals that keep V' <= bound form a half-line:
    r <= r* for b > 0, r >= r* for b < 0, with r* = (bound - a)/b - u0. Its nearest point to r (the smallest
    change) is r itself inside and r* outside. With b = 0 (or b not finite) V' does not depend on r: r is returned.
    r* is moved into the half-line by a margin of 8 eps times the magnitudes it is formed from (|bound/b|, |a/b|,
    |u0|, |r*|), more than the rounding of r* and of the sum u0 + r, so the rounded current u0 + r meets the
    condition in exact arithmetic; a residual changes by at most that margin more than the exact projection would.

    Args:
        a: the drift term of V' (V' at u = 0).
        b: the input term of V' (per mA).
        u0: the current the residual is added to [mA].
        r: the residual [mA].
        bound: the largest V' allowed, in the unit of a.
    """
    if b == 0.0 or not math.isfinite(b):
        return r
    r_star = (bound - a) / b - u0
    margin = 8.0 * EPS * (abs(bound / b) + abs(a / b) + abs(u0) + abs(r_star))
    if b > 0.0:
        lim = r_star - margin
        return r if r <= lim else lim
    lim = r_star + margin
    return r if r >= lim else lim


@jit
def _int_power(x, k):
    """x^k for an integer k >= 0 by repeated multiplication (k = n - 1 is small in practice).

    Several times cheaper than exp/log or pow; the result is within k ulp of x^k, and inf/0 only
    where x^k over-/underflows.
    """
    p = 1.0
    for _ in range(k):
        p *= x
    return p


@jit
def clf_value(s, n, sigma):
    """V = (s/sigma)^n / n."""
    ni = int(n)
    if ni == n and 0 < ni <= 16:  # n is an even integer in practice: multiplication, not pow()
        return _int_power(s / sigma, ni) / n
    return (s / sigma) ** n / n


base_current = dispatch(
    "base_current", ("law", "psi", "G", "s", "n", "sigma", "smoothing", "ulim"),
    [globals()[row.kernel] for row in LAWS], __name__, code="law",
    doc="The base current [mA] of law code ``law`` (its index in LAWS); NaN for an unknown code.")

__all__ = ["base_current", "sontag", "lin_sontag", "smooth_sign", "switching_gain", "clf_value", "decrease_clip", "EPS"]
