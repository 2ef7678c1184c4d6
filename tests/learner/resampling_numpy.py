"""The numpy implementation of Fearnhead's resampling that :mod:`.jit_resampling` replaced,
kept as the oracle of a bit-for-bit test (tests/learner/test_resampling.py): finite log
weights, more putatives than survivors and no underflow (the paths the kernels took over).
Its ``exp`` and ``log`` are the C library's (``math``) and its sums run in index order, as the
kernels' do: numpy's own ``exp`` is CPU-dependent (docs/reproducibility.md)."""

from __future__ import annotations

import math

import numpy as np

FloatArray = np.ndarray


def libm_exp(v: FloatArray) -> FloatArray:
    return np.array([math.exp(t) for t in v.tolist()])


def sum_in_order(v: FloatArray) -> float:
    total = 0.0
    for t in v.tolist():
        total += t
    return total


def numpy_resample(lv: FloatArray, n_keep: int, rng: np.random.Generator
                   ) -> tuple[np.ndarray, FloatArray, float]:
    """``(indices, log weights, 1/c)`` as the numpy code computed them."""
    top = float(lv.max())
    expw = libm_exp(lv - top)
    total = sum_in_order(expw)
    lse = top + math.log(total)
    w = expw / total
    order = np.argsort(-w, kind="stable")
    ws = w[order]
    suffix = np.cumsum(ws[::-1])[::-1]
    tau = suffix[:n_keep] / np.arange(n_keep, 0, -1)
    n_top = int(np.argmax(ws[:n_keep] <= tau))
    inv_c = float(tau[n_top])
    keep = np.zeros(lv.size, dtype=bool)
    keep[order[:n_top]] = True
    rest = np.flatnonzero(~keep)
    need = n_keep - n_top
    u0 = float(rng.uniform(0.0, inv_c))
    cum = np.cumsum(w[rest])
    crossings = np.maximum(np.ceil((cum - u0) / inv_c), 0.0)
    picked = np.empty(rest.size, dtype=bool)
    picked[0] = crossings[0] > 0.0
    np.greater(crossings[1:], crossings[:-1], out=picked[1:])
    chosen = rest[picked]
    if chosen.size > need:
        chosen = chosen[:need]
    elif chosen.size < need:
        left = rest[~picked]
        extra = left[np.argsort(-w[left], kind="stable")[: need - chosen.size]]
        chosen = np.concatenate([chosen, extra])
    new_lw = np.full(lv.size, -np.inf)
    new_lw[keep] = lv[keep] - lse
    new_lw[chosen] = math.log(inv_c)
    keep[chosen] = True
    sel = np.flatnonzero(keep)
    out = new_lw[sel]
    m = float(np.max(out))
    out -= m + math.log(sum_in_order(libm_exp(out - m)))
    return sel, out, inv_c
