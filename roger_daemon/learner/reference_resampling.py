"""Fearnhead & Clifford's optimal resampling without duplicates, in plain Python and numpy, for
:mod:`.reference` (docs/learner-math.md §5).

The fast learner's resampler (:mod:`.resampling`, compiled) makes the same steps with the same
draws; ``exp`` and ``log`` here are the C library's (``math``) and every sum runs in index
order, as there, so the two give the same floats bit for bit (tests/learner/test_resampling.py
uses this module as the compiled code's oracle).
"""

from __future__ import annotations

import math
from collections import Counter

import numpy as np
import numpy.typing as npt

__all__ = ["fearnhead_resample", "fearnhead_threshold", "log_sum_exp", "normalised_weights"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


def _sum_in_order(values: FloatArray) -> float:
    total = 0.0
    for v in values.tolist():
        total += v
    return total


def normalised_weights(lv: FloatArray) -> tuple[FloatArray, float]:
    """``(w, lse)``: ``w_i = exp(lv_i - top) / sum_j exp(lv_j - top)`` of finite log weights,
    ``top`` the largest, and ``lse = log sum_i exp(lv_i)``."""
    top = float(np.max(lv))
    expw = np.array([math.exp(v - top) for v in lv.tolist()])
    total = _sum_in_order(expw)
    return expw / total, top + math.log(total)


def log_sum_exp(lv: FloatArray) -> float:
    """``log sum_i exp(lv_i)`` of finite log weights."""
    return normalised_weights(lv)[1]


def fearnhead_threshold(w: FloatArray, n_keep: int) -> tuple[float, int]:
    """``(1/c, L)`` for normalised weights, ``len(w) > n_keep`` (§5 step 1): in decreasing
    order of weight, the first ``L`` with ``w_(L+1) <= R_L / (P - L)`` gives
    ``1/c = R_L / (P - L)``, ``R_L`` the mass outside the top ``L``."""
    ws = np.sort(w)[::-1]
    suffix = np.cumsum(ws[::-1])[::-1]  # R_L, summed from the smallest weight up
    for first in range(min(n_keep, ws.size)):
        tau = float(suffix[first] / (n_keep - first))
        if ws[first] <= tau:
            return tau, first
    return float(suffix[0] / n_keep), 0  # unreachable for 1 <= n_keep <= len(w)


def fearnhead_resample(log_weights: FloatArray, n_keep: int, rng: np.random.Generator,
                       stats: Counter[str] | None = None) -> tuple[IntArray, FloatArray]:
    """At most ``n_keep`` distinct putatives: ``(indices ascending, normalised log weights)``.

    NaN and ``-inf`` are dropped (§5 step 5, CHAMP); ``M <= P`` keeps them all; otherwise one
    uniform draw from ``rng`` (none when every survivor is kept outright by the underflow
    path's recursion, as in the fast learner).  ``stats`` counts the draws and underflows.
    """
    lw = np.asarray(log_weights, dtype=np.float64)
    if np.any(lw == np.inf):
        raise ValueError("a putative log weight is +inf")
    valid = np.flatnonzero(np.isfinite(lw))
    if valid.size == 0:
        raise ValueError("no putative has a finite log weight")
    lv = lw[valid]
    if lv.size <= n_keep:  # M <= P: keep them all
        return valid, lv - log_sum_exp(lv)
    sel, out = _resample(lv, n_keep, rng, Counter() if stats is None else stats)
    return valid[sel], out


def _resample(lv: FloatArray, n_keep: int, rng: np.random.Generator, stats: Counter[str]
              ) -> tuple[IntArray, FloatArray]:
    w, lse = normalised_weights(lv)
    order = np.argsort(-w, kind="stable")  # decreasing weight, ties by index
    inv_c, n_top = fearnhead_threshold(w, n_keep)
    if inv_c <= 0.0:  # fewer than P weights survive exp(): §5 step 5
        stats["underflows"] += 1
        return _underflow(lv, lse, order[:n_top], n_keep, rng, stats)
    keep = np.zeros(lv.size, dtype=bool)
    keep[order[:n_top]] = True  # step 2: kept with their weights
    rest = np.flatnonzero(~keep)  # step 3: stratified, in their original order
    u0 = inv_c * rng.random()  # U0 ~ U(0, 1/c)
    stats["draws"] += 1
    cum = np.cumsum(w[rest])
    crossings = np.maximum(np.ceil((cum - u0) / inv_c), 0.0)  # points U0 + j/c below cum_i
    picked = crossings > np.concatenate(([0.0], crossings[:-1]))
    chosen = rest[picked]
    need = n_keep - n_top
    if chosen.size > need:  # round-off surplus: drop the last picks
        chosen = chosen[:need]
    elif chosen.size < need:  # round-off deficit: the largest unpicked weights
        left = rest[~picked]
        chosen = np.concatenate([chosen, left[np.argsort(-w[left], kind="stable")]
                                 [: need - chosen.size]])
    new_lw = np.full(lv.size, -np.inf)
    new_lw[keep] = lv[keep] - lse
    new_lw[chosen] = math.log(inv_c)  # step 4: each pick carries 1/c
    keep[chosen] = True
    sel = np.flatnonzero(keep)
    out = new_lw[sel]
    return sel, out - log_sum_exp(out)


def _underflow(lv: FloatArray, lse: float, top: IntArray, n_keep: int,
               rng: np.random.Generator, stats: Counter[str]) -> tuple[IntArray, FloatArray]:
    """All but the ``top`` putatives underflow to weight 0: the top ones are kept with their
    weights; the rest are resampled by the same scheme on their own log weights (the
    threshold equation does not change when they are rescaled) and scaled back."""
    rest = np.setdiff1d(np.arange(lv.size), top)
    picked, out_rest = fearnhead_resample(lv[rest], n_keep - top.size, rng, stats)
    sel = np.concatenate([top, rest[picked]])
    out = np.concatenate([lv[top] - lse, out_rest + (log_sum_exp(lv[rest]) - lse)])
    order = np.argsort(sel)
    return sel[order], out[order]
