"""Small dense matrices (up to 8 x 8) in plain Python floats, with a fixed order of operations: the same bits on
every CPU.

The loop's digital filters are discretised once per setting, and their coefficients start every episode: a last-bit
difference there is carried through a switching loop to per-cent differences in an episode's metrics
(docs/REPRODUCIBILITY.md). numpy's matrix products and ``scipy.linalg.expm`` call BLAS, whose kernels (OpenBLAS picks
one by CPU) sum in an order set by the CPU's vector width, so an AVX-512 and an AVX2 machine differ in the last bit.
Here every entry is computed by Python float operations (+, -, *, /, abs, each rounded once to double precision by
IEEE-754) in loops whose order is written down, and scalings by powers of two (exact): the bits depend only on the
inputs. Python is slow, but these are a few products of matrices of at most 8 x 8 per filter setting (~1 ms), and
the filters are cached.
"""

from __future__ import annotations

import math

import numpy as np

MAX_SIZE = 8  # the largest matrix accepted: the loop's biggest is 6 x 6 (the observer's hold integrals)

# Higham (2005), "The scaling and squaring method for the matrix exponential revisited": the [13/13] Pade
# approximant's coefficients and the 1-norm up to which it is accurate to double precision (backward error <= 2^-53).
PADE13 = (64764752532480000.0, 32382376266240000.0, 7771770303897600.0, 1187353796428800.0, 129060195264000.0,
          10559470521600.0, 670442572800.0, 33522128640.0, 1323241920.0, 40840800.0, 960960.0, 16380.0, 182.0, 1.0)
THETA13 = 5.371920351148152


def _check(a, name: str) -> list[list[float]]:
    """``a`` as a list of rows of Python floats, checked square, at most MAX_SIZE and finite."""
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[0] != arr.shape[1] or not 1 <= arr.shape[0] <= MAX_SIZE:
        raise ValueError(f"{name} must be a square matrix of size 1 to {MAX_SIZE}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    return arr.tolist()


def matmul(a: list[list[float]], b: list[list[float]]) -> list[list[float]]:
    """The product a b of lists of rows, each entry summed over k = 0, 1, ... in that order."""
    cols = len(b[0])
    out = []
    for row in a:
        new = []
        for j in range(cols):
            acc = 0.0
            for k, aik in enumerate(row):
                acc += aik * b[k][j]
            new.append(acc)
        out.append(new)
    return out


def _identity(n: int) -> list[list[float]]:
    return [[1.0 if i == j else 0.0 for j in range(n)] for i in range(n)]


def _combine(terms, eye: float) -> list[list[float]]:
    """sum_t coef_t M_t + eye I over ``terms`` = [(coef, M), ...], summed in the order given."""
    n = len(terms[0][1])
    out = []
    for i in range(n):
        new = []
        for j in range(n):
            acc = eye if i == j else 0.0
            for coef, m in terms:
                acc += coef * m[i][j]
            new.append(acc)
        out.append(new)
    return out


def _norm1(a: list[list[float]]) -> float:
    """The 1-norm (largest absolute column sum)."""
    return max(sum(abs(row[j]) for row in a) for j in range(len(a)))


def _balance(a: list[list[float]]) -> list[float]:
    """Powers of two d_i such that D^-1 A D has rows and columns of similar size (Parlett and Reinsch's balancing,
    radix 2, as LAPACK's dgebal without its permutations). Companion matrices of filters have entries from 1 to
    omega_c^m: balanced, their norm is near their spectral radius, and the exponential needs fewer squarings."""
    n = len(a)
    d = [1.0] * n
    b = [row[:] for row in a]
    done = False
    while not done:
        done = True
        for i in range(n):
            c = sum(abs(b[j][i]) for j in range(n) if j != i)
            r = sum(abs(b[i][j]) for j in range(n) if j != i)
            if c == 0.0 or r == 0.0:
                continue
            s, f = c + r, 1.0
            while c < r / 2.0:
                c, f = c * 4.0, f * 2.0
            while c >= r * 2.0:
                c, f = c / 4.0, f / 2.0
            if (c + r) / f < 0.95 * s:  # (c, r) scaled by (f, 1/f): c already holds c * f^2
                done = False
                d[i] *= f
                for j in range(n):
                    b[i][j] /= f
                    b[j][i] *= f
    return d


def _solve(a: list[list[float]], b: list[list[float]]) -> list[list[float]]:
    """X with a X = b: Gaussian elimination with partial pivoting (the first largest pivot), then back substitution."""
    n = len(a)
    m = [a[i][:] + b[i][:] for i in range(n)]
    for k in range(n):
        p = max(range(k, n), key=lambda i: abs(m[i][k]))
        if m[p][k] == 0.0:
            raise ZeroDivisionError("singular matrix in the Pade approximant")
        m[k], m[p] = m[p], m[k]
        for i in range(k + 1, n):
            f = m[i][k] / m[k][k]
            for j in range(k, len(m[i])):
                m[i][j] -= f * m[k][j]
    x = [[0.0] * len(b[0]) for _ in range(n)]
    for i in range(n - 1, -1, -1):
        for j in range(len(b[0])):
            acc = m[i][n + j]
            for k in range(i + 1, n):
                acc -= m[i][k] * x[k][j]
            x[i][j] = acc / m[i][i]
    return x


def _pade13(a: list[list[float]]) -> list[list[float]]:
    """The [13/13] Pade approximant of e^a (Higham's evaluation: U odd, V even, (V - U) R = V + U)."""
    b = PADE13
    a2 = matmul(a, a)
    a4 = matmul(a2, a2)
    a6 = matmul(a4, a2)
    u = matmul(a, _combine([(1.0, matmul(a6, _combine([(b[13], a6), (b[11], a4), (b[9], a2)], 0.0))),
                            (b[7], a6), (b[5], a4), (b[3], a2)], b[1]))
    v = _combine([(1.0, matmul(a6, _combine([(b[12], a6), (b[10], a4), (b[8], a2)], 0.0))),
                  (b[6], a6), (b[4], a4), (b[2], a2)], b[0])
    n = len(a)
    return _solve([[v[i][j] - u[i][j] for j in range(n)] for i in range(n)],
                  [[v[i][j] + u[i][j] for j in range(n)] for i in range(n)])


def expm(a) -> np.ndarray:
    """e^a of a square float64 matrix of size 1 to 8, the same bits on every CPU.

    Balanced by powers of two if that lowers its 1-norm, scaled by 2^-s to a 1-norm <= 5.37, the [13/13] Pade
    approximant, squared s times, unbalanced (Higham 2005; the balancing and the scalings are exact). Accurate to a
    relative ~1e-15 times the condition of the exponential (tests/test_smallmat.py measures it against
    ``scipy.linalg.expm``).

    Args:
        a: the matrix (array-like, finite).

    Returns:
        e^a as a new (n, n) float64 array.
    """
    m = _check(a, "a")
    n = len(m)
    d = _balance(m)
    bal = [[m[i][j] * d[j] / d[i] for j in range(n)] for i in range(n)]
    if _norm1(bal) >= _norm1(m):
        d, bal = [1.0] * n, m
    norm, s = _norm1(bal), 0
    while norm > THETA13:
        norm, s = norm / 2.0, s + 1
    r = _pade13([[math.ldexp(x, -s) for x in row] for row in bal])
    for _ in range(s):
        r = matmul(r, r)
    return np.array([[r[i][j] * d[i] / d[j] for j in range(n)] for i in range(n)])
