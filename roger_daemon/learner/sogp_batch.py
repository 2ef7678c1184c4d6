"""Several experts at once: one ROGER step's evaluation and its chosen experts' updates.

:func:`evaluate_many` is :meth:`.sogp.SparseOnlineGP.terms` of every expert a step evaluates
(and, with the noise added, :func:`predict_many` a prediction's);
:func:`update_many` is :meth:`.sogp.SparseOnlineGP.update` for each expert it updates, where
the experts on the hot path (full: ``n = beta`` basis vectors in buffers for ``beta``) take
the fused add-then-delete step (:mod:`.sogp_fused`).  Both run the experts' compiled kernels
several per call, on one thread (:mod:`.jit_evaluate`) or spread over the cores
(:mod:`.jit_batch`; docs/performance.md, *Both cores in one step*); each expert's floats are
those of a call of its own.  Split from :mod:`.sogp`
(which re-exports :func:`update_many`).
"""

from __future__ import annotations

import contextlib
import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
import numpy.typing as npt

from roger_daemon.learner import jit as _jit
from roger_daemon.learner.sogp_fused import output_weights
from roger_daemon.learner.sogp_steps import LATENT_FLOOR as _LATENT_FLOOR
from roger_daemon.learner.sogp_steps import NEAR_DEPENDENT as _NEAR_DEPENDENT

if TYPE_CHECKING:
    from roger_daemon.learner.sogp import SparseOnlineGP

__all__ = ["Evaluation", "copy_many", "evaluate_many", "predict_many", "update_many"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

Terms = tuple[FloatArray, FloatArray, FloatArray, float]


def copy_many(pending: Sequence[tuple[FloatArray, FloatArray]]) -> None:
    """``np.copyto(dst, src)`` for each pair (a step's copy-on-write copies,
    :meth:`.sogp.SparseOnlineGP.copy` with ``pending``): several per compiled call
    (:func:`.jit_batch.copy_batch`) when :func:`.jit.batch_worth` says so."""
    if not _jit.batch_worth(sum(src.size for src, _ in pending)):
        for src, dst in pending:
            np.copyto(dst, src)
        return
    srcs = [src for src, _ in pending]
    dsts = [dst for _, dst in pending]
    with _jit.BATCH_LOCK:
        for lo in range(0, len(pending), _jit.WIDTH):
            hi = min(lo + _jit.WIDTH, len(pending))
            _jit.copy_batch(_jit.padded(srcs, lo), _jit.padded(dsts, lo), hi - lo)


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
    offsets: list[int]
    built: list[Terms | None]

    def terms(self, j: int) -> Terms:
        """``gps[j].terms(x)``, from the compiled ``[k, C k, k^T C k, k^T A]`` of the call."""
        got = self.built[j]
        if got is None:
            gp = self.gps[j]
            start = self.offsets[j]
            got = gp._terms_from(self.packed[start: start + 2 * gp.n + 1 + gp.a_cols])
            self.built[j] = got
        return got


def evaluate_many(gps: Sequence[SparseOnlineGP], x: FloatArray) -> Evaluation:
    """Every expert of ``gps`` (all of one model: one kernel and prior-mean setting) at
    ``x``: by compiled calls of up to :data:`.jit.WIDTH` experts each, on one thread
    (:func:`.jit_evaluate.evaluate_experts`) or, when :func:`.jit.batch_worth` says the
    experts are large enough for the threads, spread over them
    (:func:`.jit_batch.terms_batch`); the same floats as each expert's own ``terms``."""
    m = len(gps)
    columns = list(zip(*[(gp.n, gp._alloc, gp._B, gp._Cp, gp._A, gp._m) for gp in gps],
                       strict=True))
    if m == 0 or 0 in columns[0]:  # an expert without basis vectors answers with its prior
        each = [gp.terms(x) for gp in gps]
        return Evaluation(gps, np.array([t[2] for t in each]),
                          np.array([t[3] for t in each], dtype=np.float64), np.empty(0), [],
                          list(each))
    ns, allocs, bases, covs, coefs, priors = columns
    first = gps[0]
    cols = 1 + first.a_cols  # every expert of one model has as many output columns
    offsets = [0, *itertools.accumulate(2 * n + cols for n in ns)]
    packed = np.empty(offsets.pop())
    means = np.empty((m, first.d_y))
    latent = np.empty(m)
    ns_arr = np.array(ns, dtype=np.int64)
    allocs_arr = np.array(allocs, dtype=np.int64)
    offsets_arr = np.array(offsets, dtype=np.int64)  # the kernels' copy of ``offsets``
    kernel = first.kernel
    batched = _jit.batch_worth(sum(n * (n + 1) // 2 for n in ns))
    call = _jit.terms_batch if batched else _jit.evaluate_experts
    with _jit.BATCH_LOCK if batched else contextlib.nullcontext():
        for lo in range(0, m, _jit.WIDTH):
            hi = min(lo + _jit.WIDTH, m)
            call(_jit.padded(bases, lo), _jit.padded(covs, lo), _jit.padded(coefs, lo),
                 _jit.padded(priors, lo), hi - lo, ns_arr[lo:hi], allocs_arr[lo:hi], x,
                 kernel.gamma, kernel.k_star, _LATENT_FLOOR, first.prior_mean, packed,
                 offsets_arr[lo:hi], means[lo:hi], latent[lo:hi])
    return Evaluation(gps, means, latent, packed, offsets, [None] * m)


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
    test and the fused add-then-delete step (:mod:`.sogp_fused`) in compiled calls of up to
    :data:`.jit.WIDTH` experts each (:func:`.jit_batch.learn_batch`); a non-novel point then
    gets its projection update here, and an expert whose ``Q`` drifted learns on its own.
    """
    full: list[SparseOnlineGP] = []
    full_terms: list[Terms] = []
    for gp, t in zip(gps, terms, strict=True):
        if gp._fusable() and (not full or gp.n == full[0].n) and not gp.q_drifted():
            full.append(gp)
            full_terms.append(t if t is not None else gp.terms(x))
        else:
            gp.update(x, y, t)
    if not full:
        return
    kstar = full[0].kernel.k_star
    for gp, t, res in zip(full, full_terms, _learn_full(full, full_terms, x, y), strict=True):
        if res.outcome == _jit.DRIFTED:  # Q re-inverted and the point learned on its own
            gp.update(x, y, t)
            continue
        gp.record_novelty_margin(res.gamma)
        gp.n_points += 1
        if res.outcome == _jit.KEPT:  # step 4a for the non-novel few
            k, ck, mean, latent = t
            y_ext, mean = gp._targets(y, mean, k)
            s0 = gp.noise
            gp._sparse_update(ck, res.e_hat, res.gamma, -1.0 / (s0 + latent),
                              (y_ext - mean) / (s0 + latent))
        else:
            gp._dg, gp._dq, gp._dq_min, gp._dq_argmax = res.diag, res.dq, res.dq_min, \
                res.dq_argmax
        gp._clean_up()
        if res.outcome == _jit.FUSED and res.gamma < _NEAR_DEPENDENT * kstar and gp.n > 1:
            gp.refresh_inverse_gram()  # a 1/gamma-sized rank-1 term just entered Q
        gp._shift_mean(y)


class _Result(NamedTuple):
    """One full expert's steps 3-5 (:func:`.jit_batch.learn_batch`): the outcome
    (:data:`.jit.FUSED`, :data:`.jit.KEPT` or :data:`.jit.DRIFTED`), ``Q k``, ``gamma``, and
    after a fused step the diagonals it returns."""

    outcome: int
    e_hat: FloatArray
    gamma: float
    diag: FloatArray | None = None
    dq: FloatArray | None = None
    dq_min: float = math.nan
    dq_argmax: int = -1


def _learn_full(gps: Sequence[SparseOnlineGP], terms: Sequence[Terms], x: FloatArray,
                y: FloatArray) -> list[_Result]:
    """Steps 3-5 of the full experts ``gps`` (the same ``n`` and kernel): by
    :func:`.jit_batch.learn_batch`, ``WIDTH`` at a time, on several threads
    (:func:`.jit.threads`) when there is enough work (:func:`.jit.batch_worth`); else its
    body's kernels one expert at a time (faster there: docs/performance.md); the same
    floats."""
    first = gps[0]
    m = len(gps)
    qs = np.empty((m, first.a_cols))  # Csató's K1 per expert
    rs = np.empty(m)  # and K2
    for j, (gp, (k, _, mean, latent)) in enumerate(zip(gps, terms, strict=True)):
        y_ext, mean = gp._targets(y, mean, k)  # with a prior mean, the a1 column too
        denom = gp.noise + latent
        rs[j] = -1.0 / denom
        qs[j] = (y_ext - mean) / denom
    rule = np.array(first._novelty_constants())
    cw = output_weights(first.a_cols, first.d_y)
    if _jit.batch_worth(m * first.n * (first.n + 1) // 2):
        return _learn_batched(gps, terms, x, qs, rs, cw, rule)
    out: list[_Result] = []
    for gp, (k, ck, _, _), q, r in zip(gps, terms, qs, rs.tolist(), strict=True):
        e_hat, diag, dq = np.empty(gp.n), np.empty(gp.n), np.empty(gp.n)
        outcome, gamma, dq_min, dq_argmax = _jit.learn_full_expert(
            gp._B, gp._A, gp._Cp, gp._Qp, x, k, ck, gp._diag_cq(), q, r, cw, rule, e_hat,
            diag, dq)
        out.append(_Result(outcome, e_hat, gamma, diag, dq, dq_min, dq_argmax)
                   if outcome == _jit.FUSED else _Result(outcome, e_hat, gamma))
    return out


def _learn_batched(gps: Sequence[SparseOnlineGP], terms: Sequence[Terms], x: FloatArray,
                   qs: FloatArray, rs: FloatArray, cw: FloatArray, rule: FloatArray
                   ) -> list[_Result]:
    """:func:`_learn_full` by :func:`.jit_batch.learn_batch` calls."""
    m, n = len(gps), gps[0].n
    ks = np.array([t[0] for t in terms])  # rows of one length: np.array, cheaper than stack
    cks = np.array([t[1] for t in terms])
    dgs = np.array([gp._diag_cq() for gp in gps])
    e_hats, diags, dqs = np.empty((m, n)), np.empty((m, n)), np.empty((m, n))
    gammas, dq_mins = np.empty(m), np.empty(m)
    outcomes, dq_argmaxes = np.empty(m, dtype=np.int64), np.empty(m, dtype=np.int64)
    bases = [gp._B for gp in gps]
    coefs = [gp._A for gp in gps]
    cbufs = [gp._Cp for gp in gps]
    qbufs = [gp._Qp for gp in gps]
    with _jit.BATCH_LOCK:
        for lo in range(0, m, _jit.WIDTH):
            hi = min(lo + _jit.WIDTH, m)
            _jit.learn_batch(_jit.padded(bases, lo), _jit.padded(coefs, lo),
                             _jit.padded(cbufs, lo), _jit.padded(qbufs, lo), hi - lo, x,
                             ks[lo:hi], cks[lo:hi], dgs[lo:hi], qs[lo:hi], rs[lo:hi], cw, rule,
                             e_hats[lo:hi], gammas[lo:hi], outcomes[lo:hi], diags[lo:hi],
                             dqs[lo:hi], dq_mins[lo:hi], dq_argmaxes[lo:hi])
    return [_Result(o, e_hats[j], g, diags[j], dqs[j], mn, am) if o == _jit.FUSED
            else _Result(o, e_hats[j], g)
            for j, (o, g, mn, am) in enumerate(zip(outcomes.tolist(), gammas.tolist(),
                                                  dq_mins.tolist(), dq_argmaxes.tolist(),
                                                  strict=True))]
