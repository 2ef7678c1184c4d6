"""Fearnhead & Clifford's optimal resampling without duplicates (docs/learner-math.md §5).

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

import math
from functools import partial
from typing import Any

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.engine import jit as _jit

__all__ = ["fearnhead_resample", "fearnhead_threshold"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


def fearnhead_threshold(weights: FloatArray, n_keep: int) -> tuple[float, int]:
    """``(1/c, L)``: the threshold and the number of putatives kept outright.

    ``weights`` are normalised and ``len(weights) > n_keep``.  ``1/c = R_L / (P - L)`` for the
    first ``L`` (in descending order of weight) with ``w_(L+1) <= R_L / (P - L)``, where ``R_L``
    is the mass outside the top ``L`` (docs/learner-math.md §5 step 1;
    :func:`.jit_resampling.sorted_threshold`).
    """
    ws = np.ascontiguousarray(np.sort(np.asarray(weights, dtype=np.float64))[::-1])
    if ws.size < n_keep:
        raise ValueError(f"fearnhead_threshold needs at least n_keep = {n_keep} weights, "
                         f"got {ws.size}")
    inv_c, n_top = _jit.sorted_threshold(ws, n_keep)
    return float(inv_c), int(n_top)


def _decision_margin(ws: FloatArray, n_keep: int, n_top: int, inv_c: float, u0: float,
                     cum: FloatArray) -> float:
    """Smallest relative distance of a threshold test (``w_(L+1) <= R_L / (P - L)`` for L up
    to the chosen one, :func:`fearnhead_threshold`) or of a stratified crossing (``cum_i`` against
    ``U0 + j/c``) from its boundary, relative to the larger of the two compared values."""
    # the test at L = P - 1 always passes (tau = R_{P-1} >= w_P): not a decision
    n_tests = min(n_top + 1, n_keep - 1)
    tau = _jit.threshold_taus(ws, n_keep)[:n_tests]
    tested = ws[:n_tests]
    thr = float(np.min(np.abs(tested - tau) / np.maximum(tested, tau), initial=math.inf))
    points = u0 + np.maximum(np.rint((cum - u0) / inv_c), 0.0) * inv_c  # nearest U0 + j/c
    cross = float(np.min(np.abs(cum - points) / np.maximum(cum, points))) if cum.size else math.inf
    return min(thr, cross)


def fearnhead_resample(log_weights: FloatArray, n_keep: int, rng: np.random.Generator,
                       diagnostics: dict[str, Any] | None = None, *, lazy: bool = False
                       ) -> tuple[IntArray, FloatArray]:
    """Choose at most ``n_keep`` distinct putatives; return ``(indices, log_weights)``.

    Indices are in increasing order; the returned log weights are normalised (logsumexp 0).
    Exactly ``min(n_keep, number of finite log weights)`` indices are returned.  One uniform
    draw is taken from ``rng`` iff stratified resampling is needed.

    ``diagnostics``, if given, receives ``"margin"``: how far, relatively, the closest discrete
    decision of this call was from going the other way: a weight against the keep-outright
    threshold, or a cumulative weight against a stratified point ``U0 + j/c`` (``inf`` when
    every putative is kept). Round-off of another BLAS kernel can only flip a decision whose
    margin is of the order of the floats' relative error (docs/reproducibility.md).  With
    ``lazy``, ``"margin"`` is a function of no argument that computes it (a diagnostic that
    the daemon rarely reads costs nothing until it is read).

    Raises
    ------
    ValueError
        If no log weight is finite, or one is ``+inf``.
    """
    lw = np.asarray(log_weights, dtype=np.float64)
    finite = np.isfinite(lw)
    if finite.all():
        valid = None
        lv = lw
    else:  # drop NaN and -inf (CHAMP)
        if np.any(lw == np.inf):
            raise ValueError("a putative log weight is +inf")
        valid = np.flatnonzero(finite)
        if valid.size == 0:
            raise ValueError("no putative has a finite log weight")
        lv = lw[valid]
    if diagnostics is not None:
        diagnostics["margin"] = math.inf
    if lv.size <= n_keep:  # M <= P: keep them all
        keep_all = np.arange(lv.size) if valid is None else valid
        return keep_all, lv - _jit.log_sum_exp(lv)
    # the weights, the threshold, the stratified pass and the new weights: two compiled calls
    # (:mod:`.jit_resampling`; libm's exp and log); the draw stays here
    w, order, ws, inv_c, n_top, lse = _jit.fearnhead_split(lv, n_keep)
    if inv_c <= 0.0:  # fewer than P weights survive exp(): resample the rest in log space
        sel, out = _underflow_resample(lv, lse, order[:n_top], n_keep, rng)
        return (sel if valid is None else valid[sel]), out
    # stratified pass: with U0 ~ U(0, 1/c), i is picked when cum_{i-1} <= U0 + j/c < cum_i
    u0 = inv_c * rng.random()  # rng.uniform(0, inv_c)'s float: 0 + inv_c * U, U ~ U[0, 1)
    sel, out, cum = _jit.stratified_pass(w, order, n_top, n_keep, inv_c, u0, lv, lse,
                                         math.log(inv_c))
    if diagnostics is not None:
        margin = partial(_decision_margin, ws, n_keep, n_top, inv_c, u0, cum)
        diagnostics["margin"] = margin if lazy else margin()
    return (sel if valid is None else valid[sel]), out


def _underflow_resample(lv: FloatArray, lse: float, top: IntArray, n_keep: int,
                        rng: np.random.Generator) -> tuple[IntArray, FloatArray]:
    """Fearnhead's scheme when all but the ``top`` putatives underflow to weight 0.

    The top ones carry all the mass that ``exp`` can represent; with ``c`` the exact
    threshold, each of them has ``w >= 1/c`` and is kept with its weight.  The threshold
    equation restricted to the others, ``sum min(c w_i, 1) = P - L``, does not change when their
    weights are rescaled, so they are resampled by the same scheme on their own log weights and
    scaled back (``logsumexp`` of the rest).  Only reached where ``exp`` underflows, e.g. with
    a small ``theta_n`` (without it ``log(1/c) = log 0`` failed).
    """
    rest = np.setdiff1d(np.arange(lv.size), top)
    lw_rest = lv[rest]
    lse_rest = _jit.log_sum_exp(lw_rest)
    picked, out_rest = fearnhead_resample(lw_rest, n_keep - top.size, rng)
    sel = np.concatenate([top, rest[picked]])
    out = np.concatenate([lv[top] - lse, out_rest + (lse_rest - lse)])
    order = np.argsort(sel)
    return sel[order], out[order]
