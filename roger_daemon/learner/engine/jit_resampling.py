"""Compiled steps of Fearnhead & Clifford's resampling (numba; :mod:`.resampling`,
docs/learner-math.md §5).

Imported through :mod:`.jit` with the other kernels.  Sums run in index order; ``exp`` and
``log`` are the C library's (compiled ``math`` calls), not numpy's CPU-dependent SIMD loops
(docs/reproducibility.md, *numpy's SIMD loops*), so the floats are those of a plain Python
version (tests/learner/resampling_numpy.py, the oracle of tests/learner/test_resampling.py),
bit for bit, on every host.  Two calls per step instead of ~30 small numpy calls (issue 11).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.engine.jit_compile import compiled

__all__ = ["fearnhead_split", "log_sum_exp", "sorted_threshold", "stratified_pass",
           "threshold_taus"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


@compiled(nogil=True)
def threshold_taus(ws: FloatArray, n_keep: int) -> FloatArray:
    """``R_L / (P - L)`` for every ``L < min(P, len(ws))``: the right-hand side of the
    threshold test ``ws[L] <= R_L / (P - L)`` for weights ``ws`` sorted in descending order,
    ``R_L`` the mass from ``L`` on (a sum from the smallest weight up, as ``np.cumsum`` of the
    reversed weights gives it).  The one computation of the rule's values: the threshold
    (:func:`sorted_threshold`) and the resampler's decision margin read them."""
    m = ws.shape[0]
    suffix = np.empty(m)
    acc = 0.0
    for i in range(m - 1, -1, -1):
        acc += ws[i]
        suffix[i] = acc
    # never past the weights: numba does not check bounds
    taus = np.empty(min(n_keep, m))
    for first in range(taus.shape[0]):
        taus[first] = suffix[first] / float(n_keep - first)
    return taus


@compiled(nogil=True)
def sorted_threshold(ws: FloatArray, n_keep: int) -> tuple[float, int]:
    """``(1/c, L)`` for normalised weights ``ws`` sorted in descending order: the first ``L``
    with ``ws[L] <= R_L / (P - L)`` (:func:`threshold_taus`)."""
    taus = threshold_taus(ws, n_keep)
    # L = P - 1 always qualifies (tau = R_{P-1} >= ws[P-1]); the first that does is taken
    for first in range(taus.shape[0]):
        if ws[first] <= taus[first]:
            return taus[first], first
    return taus[0], 0  # unreachable for 1 <= n_keep <= m (numpy's argmax of none)


@compiled(nogil=True)
def _exp_shifted(lv: FloatArray, expw: FloatArray) -> tuple[float, float]:
    """``expw_i = exp(lv_i - top)`` for finite ``lv`` with ``top`` its largest; returns
    ``(top, total)``, ``total`` their sum in index order."""
    top = lv[0]
    for i in range(1, lv.shape[0]):
        if lv[i] > top:
            top = lv[i]
    total = 0.0
    for i in range(lv.shape[0]):
        expw[i] = math.exp(lv[i] - top)
        total += expw[i]
    return top, total


@compiled(nogil=True)
def log_sum_exp(lv: FloatArray) -> float:
    """``log sum_i exp(lv_i)`` of finite ``lv`` (:func:`_exp_shifted`)."""
    top, total = _exp_shifted(lv, np.empty(lv.shape[0]))
    return top + math.log(total)


@compiled(nogil=True)
def fearnhead_split(lv: FloatArray, n_keep: int
                    ) -> tuple[FloatArray, IntArray, FloatArray, float, int, float]:
    """``(w, order, ws, 1/c, L, lse)`` of finite log weights ``lv``: the normalised weights,
    their order by decreasing weight (ties by index), the sorted weights,
    :func:`sorted_threshold`, and :func:`log_sum_exp` of ``lv`` (its very floats)."""
    expw = np.empty(lv.shape[0])
    top, total = _exp_shifted(lv, expw)
    w = expw / total
    order = np.argsort(-w, kind="mergesort")  # stable: ties broken by index
    ws = w[order]
    inv_c, n_top = sorted_threshold(ws, n_keep)
    return w, order, ws, inv_c, n_top, top + math.log(total)


@compiled(nogil=True)
def stratified_pass(w: FloatArray, order: IntArray, n_top: int, n_keep: int, inv_c: float,
                    u0: float, lv: FloatArray, lse: float, log_inv_c: float
                    ) -> tuple[IntArray, FloatArray, FloatArray]:
    """``(selected indices, their normalised log weights, cumulative weights)``.

    The top ``n_top`` are kept with their weights ``lv - lse``; the others, in their original
    order, are picked where the running sum ``cum_i`` crosses ``u0 + j/c`` and get weight
    ``log_inv_c``; a round-off surplus drops the last picks, a deficit is topped up by the
    largest unpicked weights (:func:`.resampling.fearnhead_resample`).
    """
    m = w.shape[0]
    keep = np.zeros(m, dtype=np.bool_)
    for i in range(n_top):
        keep[order[i]] = True
    rest = np.flatnonzero(~keep)  # fixed (original) order
    need = n_keep - n_top
    cum = np.empty(rest.shape[0])
    acc = 0.0
    for j in range(rest.shape[0]):
        acc += w[rest[j]]
        cum[j] = acc
    picked = np.zeros(rest.shape[0], dtype=np.bool_)
    prev = 0.0
    n_picked = 0
    for j in range(rest.shape[0]):
        crossing = np.ceil((cum[j] - u0) / inv_c)
        if crossing < 0.0:
            crossing = 0.0
        picked[j] = crossing > prev if j > 0 else crossing > 0.0
        prev = crossing
        if picked[j]:
            n_picked += 1
    chosen = rest[picked]
    if n_picked > need:  # round-off surplus: drop the last picks
        chosen = chosen[:need]
    elif n_picked < need:  # round-off deficit: top up with the largest unpicked weights
        left = rest[~picked]
        extra = left[np.argsort(-w[left], kind="mergesort")[: need - n_picked]]
        chosen = np.concatenate((chosen, extra))
    new_lw = np.full(m, -np.inf)
    for i in range(m):
        if keep[i]:
            new_lw[i] = lv[i] - lse
    for i in chosen:
        new_lw[i] = log_inv_c
        keep[i] = True
    sel = np.flatnonzero(keep)
    out = new_lw[sel]
    out -= log_sum_exp(out)
    return sel, out, cum
