"""The compiled inverse of an SPD matrix by Cholesky (numba): the gates' every-32
recomputation (:func:`.jit_particles.gate_update`) and the re-inversion of ``Q`` up to
:data:`.jit_constants.SMALL` basis vectors (:func:`.jit_small.refresh_inverse`; LAPACK above,
faster there).

Plain loops, no BLAS or LAPACK, every sum in index order with no reassociation: the floats of
the textbook triple loops, four independent sums side by side (docs/performance.md, *A faster
compiled re-inversion*).  Imported through :mod:`.jit`; tested against those loops and numpy
(tests/learner/test_jit.py).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.engine.jit_compile import compiled as _compiled

__all__ = ["cholesky_inverse", "cholesky_inverse_logdet", "cholesky_lower",
           "lower_inverse_transposed"]

FloatArray = npt.NDArray[np.float64]


@_compiled(nogil=True)
def cholesky_lower(gram: FloatArray, n: int, jitter: float, low: FloatArray) -> float:
    """``low`` (zeros, n x n) becomes ``L`` with ``L L^T = K + jitter I``; returns
    ``log|K + jitter I|``, NaN at a pivot that is not positive.  Rows ``r..r+3`` of a column
    side by side (:func:`cholesky_inverse_logdet`)."""
    logdet = 0.0
    for j in range(n):
        s = gram[j, j] + jitter
        for p in range(j):
            s -= low[j, p] * low[j, p]
        if not s > 0.0:
            return math.nan
        d = math.sqrt(s)
        low[j, j] = d
        logdet += 2.0 * math.log(d)
        r = j + 1
        while r + 3 < n:
            t0, t1, t2, t3 = gram[r, j], gram[r + 1, j], gram[r + 2, j], gram[r + 3, j]
            for p in range(j):
                lj = low[j, p]
                t0 -= low[r, p] * lj
                t1 -= low[r + 1, p] * lj
                t2 -= low[r + 2, p] * lj
                t3 -= low[r + 3, p] * lj
            low[r, j], low[r + 1, j] = t0 / d, t1 / d
            low[r + 2, j], low[r + 3, j] = t2 / d, t3 / d
            r += 4
        for rest in range(r, n):
            t = gram[rest, j]
            for p in range(j):
                t -= low[rest, p] * low[j, p]
            low[rest, j] = t / d
    return logdet


@_compiled(nogil=True)
def lower_inverse_transposed(low: FloatArray, n: int, wt: FloatArray) -> None:
    """``wt[j, r] = W[r, j]`` for ``W = L^{-1}`` (lower triangular; ``wt`` zeros): row ``r``
    of ``W`` from those before it, ``W[r, j] = -sum_{p=j}^{r-1} L[r, p] W[p, j] / L[r, r]``,
    four entries of the row side by side (the sum of ``j + k`` starts at ``p = j + k``)."""
    for r in range(n):
        lr = low[r, r]
        wt[r, r] = 1.0 / lr
        j = 0
        while j + 3 < r:
            t0 = 0.0 - low[r, j] * wt[j, j]
            t0 -= low[r, j + 1] * wt[j, j + 1]
            t1 = 0.0 - low[r, j + 1] * wt[j + 1, j + 1]
            t0 -= low[r, j + 2] * wt[j, j + 2]
            t1 -= low[r, j + 2] * wt[j + 1, j + 2]
            t2 = 0.0 - low[r, j + 2] * wt[j + 2, j + 2]
            t3 = 0.0
            for p in range(j + 3, r):
                lp = low[r, p]
                t0 -= lp * wt[j, p]
                t1 -= lp * wt[j + 1, p]
                t2 -= lp * wt[j + 2, p]
                t3 -= lp * wt[j + 3, p]
            wt[j, r], wt[j + 1, r] = t0 / lr, t1 / lr
            wt[j + 2, r], wt[j + 3, r] = t2 / lr, t3 / lr
            j += 4
        for rest in range(j, r):
            t = 0.0
            for p in range(rest, r):
                t -= low[r, p] * wt[rest, p]
            wt[rest, r] = t / lr


@_compiled(nogil=True)
def _transposed_gram(wt: FloatArray, n: int, out: FloatArray) -> None:
    """``out[:n, :n] = W^T W`` from ``wt = W^T`` (``W`` lower triangular): entry ``(a, b)``,
    ``b <= a``, sums ``W[p, a] W[p, b]`` over ``p >= a``, four entries of a row side by side;
    exactly symmetric."""
    for a in range(n):
        b = 0
        while b + 3 <= a:
            s0 = s1 = s2 = s3 = 0.0
            for p in range(a, n):
                wa = wt[a, p]
                s0 += wa * wt[b, p]
                s1 += wa * wt[b + 1, p]
                s2 += wa * wt[b + 2, p]
                s3 += wa * wt[b + 3, p]
            out[a, b] = out[b, a] = s0
            out[a, b + 1] = out[b + 1, a] = s1
            out[a, b + 2] = out[b + 2, a] = s2
            out[a, b + 3] = out[b + 3, a] = s3
            b += 4
        for rest in range(b, a + 1):
            t = 0.0
            for p in range(a, n):
                t += wt[a, p] * wt[rest, p]
            out[a, rest] = out[rest, a] = t


@_compiled(nogil=True)
def cholesky_inverse_logdet(gram: FloatArray, n: int, jitter: float, out: FloatArray) -> float:
    """``out[:n, :n] = (K + jitter I)^{-1}`` for the SPD ``K = gram[:n, :n]``, and
    ``log|K + jitter I|`` returned; NaN (``out`` untouched) if the Cholesky factorisation
    fails.  Plain loops (no BLAS or LAPACK); the result is exactly symmetric.

    Every sum runs in index order, one multiplication and one subtraction (or addition) per
    term, no reassociation: the floats of the textbook triple loops (``L``, then ``W =
    L^{-1}``, then ``W^T W``), kept as the oracle of tests/learner/test_jit.py.  Four
    independent sums go side by side, so the CPU overlaps four chains of dependent additions
    instead of waiting on one: 2.3x as fast at n = 300, the same bits (docs/performance.md,
    *A faster compiled re-inversion*)."""
    low = np.zeros((n, n))
    logdet = cholesky_lower(gram, n, jitter, low)
    if logdet != logdet:
        return math.nan
    wt = np.zeros((n, n))
    lower_inverse_transposed(low, n, wt)
    _transposed_gram(wt, n, out)
    return logdet


@_compiled(nogil=True)
def cholesky_inverse(gram: FloatArray, n: int, jitter: float, out: FloatArray) -> bool:
    """``out[:n, :n] = (K + jitter I)^{-1}`` for the SPD ``K = gram[:n, :n]``; False (``out``
    untouched) if the Cholesky factorisation fails (:func:`cholesky_inverse_logdet`)."""
    return not math.isnan(cholesky_inverse_logdet(gram, n, jitter, out))
