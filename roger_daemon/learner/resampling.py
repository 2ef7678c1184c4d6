"""Fearnhead & Clifford's optimal resampling without duplicates (roger-math.md §5).

Given ``M`` putative particles with log weights and a target ``P < M``:

1. find the threshold ``c`` with ``sum_i min(c w_i, 1) = P`` (Fearnhead & Clifford 2003, JRSS-B);
2. keep every putative with ``w_i >= 1/c`` with its weight unchanged;
3. resample the others by stratified sampling (Carpenter, Clifford & Fearnhead 1999) in their
   original order: ``U ~ Uniform(0, 1/c)``, select ``i`` when the running sum crosses
   ``U + j/c``; each survivor gets weight ``1/c``.  Every remaining ``w_i < 1/c``, so nothing is
   selected twice.

Each putative survives with probability ``min(1, c w_i)`` and carries weight
``w_i / min(1, c w_i)``: the scheme is unbiased and duplicate-free.  Round-off guards (§5 step
5, pitfall 12): NaN and ``-inf`` log weights are dropped; the stratified pass is corrected to
exactly ``P - L`` picks (top-up by largest weight, or dropping a surplus last pick); weights
are returned in log space so that tiny survivors do not underflow.  ``M <= P`` keeps them all.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

__all__ = ["fearnhead_resample", "fearnhead_threshold"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


def _logsumexp(lw: FloatArray) -> float:
    m = float(np.max(lw))
    return m + float(np.log(np.sum(np.exp(lw - m))))


def fearnhead_threshold(weights: FloatArray, n_keep: int) -> tuple[float, int]:
    """``(1/c, L)``: the threshold and the number of putatives kept outright.

    ``weights`` are normalised and ``len(weights) > n_keep``.  ``1/c = R_L / (P - L)`` for the
    first ``L`` (in descending order of weight) with ``w_(L+1) <= R_L / (P - L)``, where ``R_L``
    is the mass outside the top ``L`` (roger-math.md §5 step 1).
    """
    ws = np.sort(weights)[::-1]
    suffix = np.cumsum(ws[::-1])[::-1]  # suffix[L] = sum_{j >= L} ws[j] = R_L
    ells = np.arange(n_keep)
    tau = suffix[:n_keep] / (n_keep - ells)
    # L = P - 1 always qualifies (tau = R_{P-1} >= ws[P-1]); argmax finds the first True
    first = int(np.argmax(ws[:n_keep] <= tau))
    return float(tau[first]), first


def fearnhead_resample(log_weights: FloatArray, n_keep: int,
                       rng: np.random.Generator) -> tuple[IntArray, FloatArray]:
    """Choose at most ``n_keep`` distinct putatives; return ``(indices, log_weights)``.

    Indices are in increasing order; the returned log weights are normalised (logsumexp 0).
    Exactly ``min(n_keep, number of finite log weights)`` indices are returned.  One uniform
    draw is taken from ``rng`` iff stratified resampling is needed.

    Raises
    ------
    ValueError
        If no log weight is finite, or one is ``+inf``.
    """
    lw = np.asarray(log_weights, dtype=np.float64)
    if np.any(np.isposinf(lw)):
        raise ValueError("a putative log weight is +inf")
    valid = np.flatnonzero(np.isfinite(lw))  # drop NaN and -inf (CHAMP)
    if valid.size == 0:
        raise ValueError("no putative has a finite log weight")
    if valid.size <= n_keep:
        out = lw[valid]
        return valid.astype(np.int64), out - _logsumexp(out)
    lv = lw[valid]
    lse = _logsumexp(lv)
    w = np.exp(lv - lse)
    inv_c, n_top = fearnhead_threshold(w, n_keep)
    # keep the top L outright (stable order: ties broken by index)
    order = np.argsort(-w, kind="stable")
    keep = np.zeros(valid.size, dtype=bool)
    keep[order[:n_top]] = True
    rest = np.flatnonzero(~keep)  # fixed (original) order
    need = n_keep - n_top
    # stratified pass: with U0 ~ U(0, 1/c), i is picked when cum_{i-1} <= U0 + j/c < cum_i
    u0 = float(rng.uniform(0.0, inv_c))
    cum = np.cumsum(w[rest])
    crossings = np.maximum(np.ceil((cum - u0) / inv_c), 0.0)
    picked = np.diff(crossings, prepend=0.0) > 0
    chosen = rest[picked]
    if chosen.size > need:  # round-off surplus: drop the last picks
        chosen = chosen[:need]
    elif chosen.size < need:  # round-off deficit: top up with the largest unpicked weights
        left = rest[~picked]
        extra = left[np.argsort(-w[left], kind="stable")[: need - chosen.size]]
        chosen = np.concatenate([chosen, extra])
    new_lw = np.empty(valid.size)
    new_lw[:] = -np.inf
    new_lw[keep] = lv[keep] - lse
    new_lw[chosen] = np.log(inv_c)
    sel = np.sort(np.concatenate([np.flatnonzero(keep), chosen]))
    out = new_lw[sel]
    return valid[sel].astype(np.int64), out - _logsumexp(out)
