"""Several experts' kernels in one compiled call, spread over the cores (numba ``prange``).

A learner step evaluates every distinct expert on the new point and then updates each chosen
one (paper Algorithm 1; docs/learner-math.md §4).  The experts are independent, so these
kernels run the per-expert bodies of :mod:`.jit_kernels` and :mod:`.jit_fused` for up to
:data:`.jit.WIDTH` experts per call (the evaluation's :data:`.jit.EVALUATION_WIDTH`): each
expert's floats are computed by one thread, in the same order whatever the number of threads
or the thread, so the results do not depend on them (tested; docs/performance.md, *Both
cores in one step*).

Which thread takes which expert is the caller's: the parallel loop has one iteration per
thread (``groups``), iteration ``g`` takes the experts whose ``owners`` entry is ``g``, and
numba's static schedule runs iteration ``g`` on thread ``g``.  The caller keeps each expert
on the thread that took it last (its *home*, :func:`balanced_owners`), so its matrices stay
in that core's caches: when a host places the two cores far apart, an expert that changes
thread is read across the machine (docs/performance.md, *The slow spells are the two cores
far apart*).

The experts come as a tuple of exactly that many slabs (:func:`.jit.padded`; each expert's
buffers in one array, :mod:`.jit_slab`), so each kernel has one compiled signature whatever
the number of experts; only the first ``count`` entries are read.  The number of threads is
set by :func:`.jit.set_threads`.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from numba import prange

from roger_daemon.learner.engine.jit_compile import compiled as _compiled
from roger_daemon.learner.engine.jit_constants import DRIFTED, FUSED, KEPT
from roger_daemon.learner.engine.jit_evaluate import evaluate_slab, slab_views
from roger_daemon.learner.engine.jit_fused import fused_step
from roger_daemon.learner.engine.jit_kernels import (
    keeps_basis_vectors,
    novelty_margin,
    novelty_test,
    projection,
)

__all__ = ["balanced_owners", "copy_batch", "learn_batch", "learn_full_expert", "terms_batch"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


@_compiled(parallel=True, nogil=True)
def terms_batch(slabs: tuple[FloatArray, ...], count: int, ns: IntArray, x: FloatArray,
                gamma: float, k_star: float, floor: float, prior_mean: bool, out: FloatArray,
                offsets: IntArray, means: FloatArray, latent: FloatArray, owners: IntArray,
                groups: int) -> None:
    """:func:`.jit_evaluate.evaluate_experts` with the experts spread over the threads: expert
    ``e``'s ``[k, C k, k^T C k, k^T A]`` written at ``out[offsets[e]:]``, its predictive mean
    into ``means[e]``, its latent variance into ``latent[e]``; by iteration ``owners[e]`` of
    ``groups`` (:func:`balanced_owners`)."""
    for g in prange(groups):
        for e in range(count):
            if owners[e] == g:
                latent[e] = evaluate_slab(slabs[e], ns[e], x, gamma, k_star, floor, prior_mean,
                                          out, offsets[e], means[e])


@_compiled(nogil=True)
def learn_full_expert(basis: FloatArray, coef: FloatArray, cbuf: FloatArray, qbuf: FloatArray,
                      x: FloatArray, k: FloatArray, ck: FloatArray, dg: FloatArray,
                      q: FloatArray, r: float, cw: FloatArray, rule: FloatArray,
                      e_hat_out: FloatArray, diag_out: FloatArray, dq_out: FloatArray
                      ) -> tuple[int, float, float, int, float, bool]:
    """Steps 3-5 of learning ``x`` in one full expert (``n`` basis vectors in buffers for
    ``n``; docs/learner-math.md §2.5): ``Q k`` and the novelty test
    (:func:`.jit_kernels.projection`, :func:`.jit_kernels.novelty_test` with
    ``rule = [k*, threshold, floor, drift_tol, clean-up floor]``), then, for a novel point,
    the fused add-then-delete step (:func:`.jit_fused.fused_step`) while ``Q`` is still in the
    core's cache.  In: its kernel vector ``k``, ``C k``, ``diag(C) + diag(Q)``, Csató's
    ``K1`` (``q``) and ``K2`` (``r``).  Writes ``Q k`` into ``e_hat_out`` and, after a fused
    step, the diagonals it returns into ``diag_out`` and ``dq_out``; returns ``(outcome,
    gamma, min(dq), argmax(dq), novelty margin, clean)``, the outcome :data:`.jit.FUSED`,
    :data:`.jit.KEPT` (not novel: left to the caller's projection update) or
    :data:`.jit.DRIFTED` (``Q`` must be re-inverted first; nothing done), the margin of the
    novelty test (:func:`.jit_kernels.novelty_margin`) and, after a fused step, whether the
    geometric clean-up keeps every basis vector (:func:`.jit_kernels.keeps_basis_vectors`).
    One expert at a time (one thread) or several (:func:`learn_batch`)."""
    n = k.shape[0]
    e_hat, kqk = projection(qbuf, k, n, n)
    gamma, drifted, novel = novelty_test(kqk, rule[0], rule[1], rule[2], rule[3])
    e_hat_out[:] = e_hat
    if drifted:
        return DRIFTED, gamma, math.nan, -1, math.nan, False
    margin = novelty_margin(gamma, rule[0], rule[1])
    if not novel:
        return KEPT, gamma, math.nan, -1, margin, False
    diag, dq, dq_min, dq_argmax = fused_step(basis, coef, cbuf, qbuf, dg, x, ck, e_hat, cw, q,
                                             r, gamma)
    diag_out[:] = diag
    dq_out[:] = dq
    clean = n <= 1 or keeps_basis_vectors(dq[dq_argmax], rule[4])
    return FUSED, gamma, dq_min, dq_argmax, margin, clean


@_compiled(parallel=True, nogil=True)
def learn_batch(slabs: tuple[FloatArray, ...], count: int, x: FloatArray, terms: FloatArray,
                starts: IntArray, dgs: FloatArray, qs: FloatArray, rs: FloatArray,
                cw: FloatArray, rule: FloatArray, e_hats: FloatArray, gammas: FloatArray,
                outcomes: IntArray, diags: FloatArray, dqs: FloatArray, dq_mins: FloatArray,
                dq_argmaxes: IntArray, margins: FloatArray, clean: npt.NDArray[np.bool_],
                owners: IntArray, groups: int) -> None:
    """:func:`learn_full_expert` of each of the first ``count`` full experts, given by their
    slabs (:mod:`.jit_slab`; ``n`` basis vectors in buffers for ``n``, ``n`` the width of
    ``e_hats``), one row or entry each of the per-expert inputs
    (``dgs``, ``qs``, ``rs``) and results (``e_hats``, ``diags``, ``dqs``; ``outcomes``,
    ``gammas``, ``dq_mins``, ``dq_argmaxes``, ``margins``, ``clean``); expert ``e``'s kernel
    vector and ``C k`` are ``terms[starts[e]:]`` and ``terms[starts[e] + n:]`` (an
    evaluation's packed terms, :func:`.jit_evaluate.evaluate_expert`, read where they are)."""
    n = e_hats.shape[1]
    for g in prange(groups):
        for e in range(count):
            if owners[e] == g:
                at = starts[e]
                cbuf, qbuf, basis, coef, _ = slab_views(slabs[e])
                outcome, gamma, dq_min, dq_argmax, margin, kept = learn_full_expert(
                    basis, coef, cbuf, qbuf, x, terms[at: at + n],
                    terms[at + n: at + 2 * n], dgs[e], qs[e], rs[e], cw, rule, e_hats[e],
                    diags[e], dqs[e])
                outcomes[e] = outcome
                gammas[e] = gamma
                dq_mins[e] = dq_min
                dq_argmaxes[e] = dq_argmax
                margins[e] = margin
                clean[e] = kept


@_compiled(parallel=True, nogil=True)
def copy_batch(srcs: tuple[FloatArray, ...], dsts: tuple[FloatArray, ...], count: int,
               owners: IntArray, groups: int) -> None:
    """``dsts[e][:] = srcs[e]`` for the first ``count`` pairs: a step's copy-on-write copies
    (:func:`.buffers.copy_many`); by iteration ``owners[e]`` of ``groups``."""
    for g in prange(groups):
        for e in range(count):
            if owners[e] == g:
                dsts[e][:] = srcs[e]


@_compiled(nogil=True)
def balanced_owners(homes: IntArray, work: IntArray, groups: int, rebalance: bool) -> IntArray:
    """Which of ``groups`` iterations takes each expert: its home ``homes[e]`` where it has
    one (``0 <= home < groups``); the others, in order, the least loaded; then, with
    ``rebalance``, experts moved from the most to the least loaded group while a move
    narrows the gap between them (the largest ``work`` that fits, the last of equals)."""
    m = homes.shape[0]
    owners = np.empty(m, dtype=np.int64)
    load = np.zeros(groups, dtype=np.int64)
    for e in range(m):
        owners[e] = homes[e] if 0 <= homes[e] < groups else -1
        if owners[e] >= 0:
            load[owners[e]] += work[e]
    for e in range(m):
        if owners[e] < 0:
            g = int(np.argmin(load))
            owners[e] = g
            load[g] += work[e]
    while rebalance:
        hi = int(np.argmax(load))
        lo = int(np.argmin(load))
        gap = load[hi] - load[lo]
        pick = -1
        for e in range(m):
            if owners[e] == hi and 0 < work[e] < gap and (pick < 0 or work[e] >= work[pick]):
                pick = e
        if pick < 0:
            break
        owners[pick] = lo
        load[hi] -= work[pick]
        load[lo] += work[pick]
    return owners
