"""Several experts at once: one ROGER step's evaluation and its chosen experts' updates.

:func:`evaluate_many` is :meth:`.sogp.SparseOnlineGP.terms` of every expert a step evaluates
(and, with the noise added, :func:`predict_many` a prediction's);
:func:`update_many` is :meth:`.sogp.SparseOnlineGP.update` for each expert it updates, where
the experts on the hot path (full: ``n = beta`` basis vectors in buffers for ``beta``) take
the fused add-then-delete step (:mod:`.engine.jit_fused`).  Both run the experts' compiled kernels
several per call, on one thread (:mod:`.jit_evaluate`) or spread over the cores
(:mod:`.jit_batch`; docs/performance.md, *Both cores in one step*); each expert's floats are
those of a call of its own.  Split from :mod:`.sogp`
(which re-exports :func:`update_many`).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from itertools import accumulate
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.engine import jit as _jit
from roger_daemon.learner.engine.jit_slab import output_weights
from roger_daemon.learner.sogp import SparseOnlineGP
from roger_daemon.learner.sogp_steps import LATENT_FLOOR as _LATENT_FLOOR
from roger_daemon.learner.sogp_steps import NEAR_DEPENDENT as _NEAR_DEPENDENT

__all__ = ["Evaluation", "evaluate_many", "predict_many", "update_evaluated", "update_many"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

Terms = tuple[FloatArray, FloatArray, FloatArray, float]


@dataclass(slots=True)
class Evaluation:
    """Experts evaluated at one input (:func:`evaluate_many`): ``means[j]`` (``d_y``) and
    ``latent[j]`` are expert ``gps[j]``'s predictive mean and latent variance (the floats of
    :meth:`.sogp.SparseOnlineGP.terms`); :meth:`terms` gives its full terms, built from the
    compiled ``packed[offsets[j]:]`` when first asked for (a step updates ~3 of the ~25 experts
    it evaluates) and kept in ``built``."""

    gps: Sequence[SparseOnlineGP]
    means: FloatArray
    latent: FloatArray
    packed: FloatArray
    offsets: IntArray
    built: list[Terms | None]

    def terms(self, j: int) -> Terms:
        """``gps[j].terms(x)``, from the compiled ``[k, C k, k^T C k, k^T A]`` of the call."""
        got = self.built[j]
        if got is None:
            gp = self.gps[j]
            start = int(self.offsets[j])
            got = gp._terms_from(self.packed[start: start + 2 * gp.n + 1 + gp.a_cols])
            self.built[j] = got
        return got


def evaluate_many(gps: Sequence[SparseOnlineGP], x: FloatArray) -> Evaluation:
    """Every expert of ``gps`` (all of one model: one kernel and prior-mean setting) at
    ``x``: by compiled calls of up to :data:`.jit.EVALUATION_WIDTH` experts each, on one
    thread (:func:`.jit_evaluate.evaluate_experts`) or, when :func:`.jit.batch_worth` says the
    experts are large enough for the threads, spread over them
    (:func:`.jit_batch.terms_batch`); the same floats as each expert's own ``terms``."""
    m = len(gps)
    ns = [gp.n for gp in gps]
    if m == 0 or 0 in ns:  # an expert without basis vectors answers with its prior
        each = [gp.terms(x) for gp in gps]
        return Evaluation(gps, np.array([t[2] for t in each]),
                          np.array([t[3] for t in each], dtype=np.float64), np.empty(0),
                          np.zeros(m, dtype=np.int64), list(each))
    first = gps[0]
    cols = 1 + first.a_cols  # every expert of one model has as many output columns
    sizes = [2 * n + cols for n in ns]  # each expert's terms, one after the other in ``packed``
    bounds = np.fromiter(accumulate(sizes, initial=0), dtype=np.int64, count=m + 1)
    offsets = bounds[:m]  # where each expert's terms start in ``packed``
    packed = np.empty(int(bounds[m]))
    means = np.empty((m, first.d_y))
    latent = np.empty(m)
    kernel = first.kernel
    batched = _jit.batch_worth(sum(n * (n + 1) for n in ns) // 2)  # packed entries in all
    ns_arr = np.array(ns, dtype=np.int64)
    slabs = [gp._slab for gp in gps]  # each expert's buffers in one array (.jit_slab)
    width = _jit.EVALUATION_WIDTH
    owners, groups = _owners(gps, ns_arr * (ns_arr + 1) // 2) if batched else (None, 0)
    with _jit.BATCH_LOCK if batched else contextlib.nullcontext():
        for lo in range(0, m, width):
            hi = min(lo + width, m)
            args = (_jit.padded(slabs, lo, width), hi - lo, ns_arr[lo:hi], x, kernel.gamma,
                    kernel.k_star, _LATENT_FLOOR, first.prior_mean, packed, offsets[lo:hi],
                    means[lo:hi], latent[lo:hi])
            if owners is None:
                _jit.evaluate_experts(*args)
            else:
                _jit.terms_batch(*args, owners[lo:hi], groups)
    return Evaluation(gps, means, latent, packed, offsets, [None] * m)


def _owners(gps: Sequence[SparseOnlineGP], work: IntArray) -> tuple[IntArray, int]:
    """Each expert's thread for a batched kernel (:func:`.jit_batch.balanced_owners`: its home
    where the threads' loads allow), kept as its new home; and the number of threads."""
    groups = _jit.threads()
    owners = _jit.balanced_owners(np.array([gp.home for gp in gps], dtype=np.int64), work,
                                  groups, True)
    for gp, owner in zip(gps, owners.tolist(), strict=True):
        gp.home = owner
    return owners, groups


def predict_many(gps: Sequence[SparseOnlineGP], x: FloatArray, means: FloatArray,
                 variance: FloatArray) -> None:
    """``means[j], variance[j] = gps[j].predict(x)`` for every expert (a prediction's multimap,
    docs/learner-math.md §6): :func:`evaluate_many`, then the observation noise added to each
    latent variance, the same floats; all of one model (one kernel, noise and prior-mean
    setting)."""
    if not gps:
        return
    got = evaluate_many(gps, x)
    means[:] = got.means
    np.add(gps[0].noise, got.latent, out=variance)


def update_many(gps: Sequence[SparseOnlineGP], x: FloatArray, y: FloatArray,
                terms: Sequence[Terms | None]) -> None:
    """Learn the same pair in several distinct experts (one ROGER step's chosen experts).

    Equivalent to ``gp.update(x, y, t)`` for each (except that a non-novel point never
    re-inverts ``Q``: a projection update leaves ``Q`` unchanged).  The experts on the hot path
    (full, contiguous, the same ``n``, no drift in ``diag(Q)``) take ``Q k``, the novelty
    test and the fused add-then-delete step (:mod:`.engine.jit_fused`) in compiled calls of up to
    :data:`.jit.WIDTH` experts each (:func:`.jit_batch.learn_batch`); a non-novel point then
    gets its projection update here, and an expert whose ``Q`` drifted learns on its own.
    """
    full, alone = _hot_path(gps)
    _learn_alone(gps, alone, x, y, terms.__getitem__)
    if not full:
        return
    got: list[Terms] = []
    for j in full:
        t = terms[j]
        got.append(t if t is not None else gps[j].terms(x))
    n = gps[full[0]].n  # [k, C k] of each expert, one after the other, as an evaluation's
    _learn_full([gps[j] for j in full], x, y, np.concatenate([v for t in got for v in t[:2]]),
                np.arange(len(got), dtype=np.int64) * (2 * n), np.array([t[2] for t in got]),
                np.array([t[3] for t in got], dtype=np.float64), got.__getitem__)


def update_evaluated(gps: Sequence[SparseOnlineGP], x: FloatArray, y: FloatArray,
                     evaluated: Sequence[tuple[Evaluation, int] | None]) -> None:
    """:func:`update_many` with each expert's terms where the step's evaluation left them
    (``(evaluation, j)``: :meth:`Evaluation.terms` of ``j``; ``None``: not evaluated): the hot
    path's kernel vectors, ``C k``, means and latent variances are read off the evaluation's
    arrays, the same floats, without a tuple of terms per expert (a step updates ~10)."""
    full, alone = _hot_path(gps)
    _learn_alone(gps, alone, x, y,
                 lambda j: None if (ref := evaluated[j]) is None else ref[0].terms(ref[1]))
    if not full:
        return
    refs = [evaluated[j] for j in full]
    ev = refs[0][0] if refs[0] is not None else None
    if ev is None or gps[full[0]].prior_mean or any(r is None or r[0] is not ev for r in refs):
        update_many([gps[j] for j in full], x, y,
                    [None if r is None else r[0].terms(r[1]) for r in refs])
        return
    rows = np.array([r[1] for r in refs if r is not None], dtype=np.int64)
    _learn_full([gps[j] for j in full], x, y, ev.packed, ev.offsets[rows], ev.means[rows],
                ev.latent[rows], lambda i: ev.terms(int(rows[i])))


def _hot_path(gps: Sequence[SparseOnlineGP]) -> tuple[list[int], list[int]]:
    """Indices of the experts that take the batched fused step (full in buffers for exactly
    ``beta``, the same ``n`` as the first of them, ``diag(Q)`` without drift), and of the
    others."""
    full: list[int] = []
    alone: list[int] = []
    n = -1
    for j, gp in enumerate(gps):
        if gp._fusable() and (n < 0 or gp.n == n) and not gp.q_drifted():
            full.append(j)
            n = gp.n
        else:
            alone.append(j)
    return full, alone


def _learn_alone(gps: Sequence[SparseOnlineGP], alone: list[int], x: FloatArray, y: FloatArray,
                 terms_of: Callable[[int], Terms | None]) -> None:
    """The experts off the hot path (``alone``) learn one at a time, with their terms where
    known (``terms_of(j)``, ``None``: computed by the update)."""
    for j in alone:
        gps[j].update(x, y, terms_of(j))


def _learn_full(gps: Sequence[SparseOnlineGP], x: FloatArray, y: FloatArray, terms: FloatArray,
                starts: IntArray, means: FloatArray, latent: FloatArray,
                terms_of: Callable[[int], Terms]) -> None:
    """Steps 3-6 of the full experts ``gps`` (of one model: the same ``n``, kernel, noise and
    novelty rule): expert ``i``'s kernel vector and ``C k`` at ``terms[starts[i]:]`` one after
    the other (as an evaluation packs them), its predictive mean and latent variance a row of
    ``means`` and ``latent`` (``terms_of(i)``: its terms, for the few that need them); by
    :func:`.jit_batch.learn_batch`, ``WIDTH`` at a time, on several threads
    (:func:`.jit.threads`) when there is enough work (:func:`.jit.batch_worth`); else its
    body's kernels one expert at a time (faster there: docs/performance.md); the same
    floats."""
    first = gps[0]
    m, n = len(gps), first.n
    denom = first.noise + latent
    rs = -1.0 / denom  # Csató's K2 per expert
    if first.prior_mean:  # the a1 column too (:meth:`.sogp.SparseOnlineGP._targets`)
        qs = np.empty((m, first.a_cols))  # and K1
        for j, gp in enumerate(gps):
            at = int(starts[j])
            y_ext, mean = gp._targets(y, means[j], terms[at: at + n])
            qs[j] = (y_ext - mean) / denom[j]
    else:
        qs = (y - means) / denom[:, None]
    rule = np.array([*first._novelty_constants(), first.cleanup_floor()])
    cw = output_weights(first.a_cols, first.d_y)
    rows = np.empty((3, m, n))  # Q k, and the diagonals a fused step writes
    out = _Outcomes(np.empty(m, dtype=np.int64), np.empty(m), rows[0], rows[1], rows[2],
                    np.empty(m), np.empty(m, dtype=np.int64), np.empty(m),
                    np.empty(m, dtype=np.bool_))
    dgs = np.array([gp._diag_cq() for gp in gps])
    if _jit.batch_worth(m * n * (n + 1) // 2):
        _learn_batched(gps, x, terms, starts, dgs, qs, rs, cw, rule, out)
    else:
        for j, (gp, at) in enumerate(zip(gps, starts.tolist(), strict=True)):
            (out.outcome[j], out.gamma[j], out.dq_min[j], out.dq_argmax[j], out.margin[j],
             out.clean[j]) = _jit.learn_full_expert(
                gp._B, gp._A, gp._Cp, gp._Qp, x, terms[at: at + n], terms[at + n: at + 2 * n],
                dgs[j], qs[j], rs[j], cw, rule, out.e_hat[j], out.diag[j], out.dq[j])
    _finish(gps, x, y, out, terms_of)


class _Outcomes(NamedTuple):
    """The full experts' steps 3-5 (:func:`.jit_batch.learn_batch`), one entry or row each:
    the outcome (:data:`.jit.FUSED`, :data:`.jit.KEPT` or :data:`.jit.DRIFTED`), ``gamma``,
    ``Q k``, after a fused step the diagonals it returns with ``diag(Q)``'s minimum and
    first argmax, the novelty test's margin, and whether the clean-up keeps every basis
    vector."""

    outcome: IntArray
    gamma: FloatArray
    e_hat: FloatArray
    diag: FloatArray
    dq: FloatArray
    dq_min: FloatArray
    dq_argmax: IntArray
    margin: FloatArray
    clean: npt.NDArray[np.bool_]


def _learn_batched(gps: Sequence[SparseOnlineGP], x: FloatArray, terms: FloatArray,
                   starts: IntArray, dgs: FloatArray, qs: FloatArray, rs: FloatArray,
                   cw: FloatArray, rule: FloatArray, out: _Outcomes) -> None:
    """:func:`_learn_full`'s kernels by :func:`.jit_batch.learn_batch` calls."""
    slabs = [gp._slab for gp in gps]  # each expert's buffers in one array (.jit_slab)
    owners, groups = _owners(gps, np.ones(len(gps), dtype=np.int64))
    with _jit.BATCH_LOCK:
        for lo in range(0, len(gps), _jit.WIDTH):
            hi = min(lo + _jit.WIDTH, len(gps))
            _jit.learn_batch(_jit.padded(slabs, lo), hi - lo, x,
                             terms, starts[lo:hi], dgs[lo:hi], qs[lo:hi], rs[lo:hi], cw, rule,
                             out.e_hat[lo:hi], out.gamma[lo:hi], out.outcome[lo:hi],
                             out.diag[lo:hi], out.dq[lo:hi], out.dq_min[lo:hi],
                             out.dq_argmax[lo:hi], out.margin[lo:hi], out.clean[lo:hi],
                             owners[lo:hi], groups)


def _finish(gps: Sequence[SparseOnlineGP], x: FloatArray, y: FloatArray, out: _Outcomes,
            terms_of: Callable[[int], Terms]) -> None:
    """After the kernels: each expert's novelty margin and point count; a non-novel point's
    projection update (step 4a); the fused step's diagonals kept; the clean-up (step 6) where
    ``diag(Q)``'s largest entry says one is due; ``Q`` re-inverted after a near-dependent
    basis vector; the prior mean moved.  An expert whose ``Q`` drifted learns on its own."""
    kstar = gps[0].kernel.k_star
    margins, clean = out.margin.tolist(), out.clean.tolist()
    gammas = out.gamma.tolist()
    dq_mins, dq_argmaxes = out.dq_min.tolist(), out.dq_argmax.tolist()
    diags, dqs = list(out.diag), list(out.dq)  # row views, made in one call
    for j, (gp, outcome) in enumerate(zip(gps, out.outcome.tolist(), strict=True)):
        if outcome == _jit.DRIFTED:  # Q re-inverted and the point learned on its own
            gp.update(x, y, terms_of(j))
            continue
        gp.novelty_margin = margins[j]
        gp.n_points += 1
        if outcome == _jit.KEPT:  # step 4a for the non-novel few
            k, ck, mean, latent = terms_of(j)
            y_ext, mean = gp._targets(y, mean, k)
            s0 = gp.noise
            gp._sparse_update(ck, out.e_hat[j], gammas[j], -1.0 / (s0 + latent),
                              (y_ext - mean) / (s0 + latent))
            gp._clean_up()
        else:
            gp._dg, gp._dq = diags[j], dqs[j]
            gp._dq_min, gp._dq_argmax = dq_mins[j], dq_argmaxes[j]
            if not (clean[j] and gp.n == gp.capacity):
                gp._clean_up()
            if gammas[j] < _NEAR_DEPENDENT * kstar and gp.n > 1:
                gp.refresh_inverse_gram()  # a 1/gamma-sized rank-1 term just entered Q
        if gp.prior_mean:
            gp._shift_mean(y)
