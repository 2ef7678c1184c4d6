"""One ROGER learning step (paper Algorithm 1, docs/learner-math.md §4), on a :class:`.Roger`.

:func:`putatives` computes the log weight of every putative (each particle's experts plus one
new empty expert) from predictive quantities only, touching no expert; after resampling,
:func:`instantiate` builds the survivors and incorporates the point into each chosen expert
once (copy-on-write of the slots shared with survivors that keep the old version).  Split from
:mod:`.roger`, whose private state these functions read and write.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.engine import jit as _jit
from roger_daemon.learner.sogp import SparseOnlineGP
from roger_daemon.learner.sogp_batch import (
    Evaluation,
    copy_many,
    evaluate_many,
    update_evaluated,
)

if TYPE_CHECKING:
    from roger_daemon.learner.engine.buffers import PendingCopy
    from roger_daemon.learner.roger import Roger

__all__ = ["SlotTerms", "instantiate", "putatives"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
#: the step's evaluated experts by slot: where each one's terms are (an update reuses its
#: expert's, built only then: :meth:`.sogp_batch.Evaluation.terms`)
SlotTerms = dict[int, tuple[Evaluation, int]]

_STAGE1 = 4  # experts evaluated first to sharpen the pruning bound


def putatives(model: Roger, xs: FloatArray, ys: FloatArray
               ) -> tuple[FloatArray, IntArray, IntArray, IntArray, SlotTerms]:
    """Log weights of all putatives (Algorithm 1, inner loops), touching no expert.

    Putative ``j`` assigns the point to expert slot ``flat_slots[j]`` (``-1``: a new one)
    of particle ``flat_part[j]``; particle ``p``'s putatives start at ``offsets[p]``.
    """
    p = model.params
    cap = len(model._gps)
    # gates of all unique experts, batched (§3.4); CRP prior n_k (N + alpha dropped, §4)
    live = np.flatnonzero(model._ref > 0)
    slot_gate = np.zeros(cap)
    model._gates.crp_log_terms(live, xs, model._npts, slot_gate)
    # each particle's putatives: its experts, then the new one (:mod:`.jit_layout`)
    flat_slots, flat_part, offsets, base = _jit.putative_layout(
        model._slots, model._starts, model._logw, slot_gate,
        model._log_alpha + model._gates.prior_log_predictive(xs))
    if p.sticky_kappa > 0.0 and model.n_learned > 0:
        add_stickiness(model, base, flat_part, flat_slots)

    # GP factor: the empty expert analytically, the others once per unique expert
    yy = _jit.dot_column(ys, ys.reshape(-1, 1), 0, model.d_y)  # |y|^2 in index order, no BLAS
    ll_new = _jit.gaussian_log_density(yy, model._empty_var, model._ll_dims)
    slot_ll, terms = gp_factors(model, xs, ys, live, base, flat_slots, ll_new, cap)
    lw = _jit.putative_log_weights(base, flat_slots, slot_ll, ll_new)
    return lw, flat_part, flat_slots, offsets, terms


def add_stickiness(model: Roger, base: FloatArray, flat_part: IntArray, flat_slots: IntArray
                    ) -> None:
    """Sticky CRP (Fox et al. 2008; paper section V): the expert of the previous point in
    each particle weighs ``n_k + kappa`` instead of ``n_k``; with ``kappa = inf`` every
    other putative of that particle gets weight 0.  The common normaliser
    ``N + alpha + kappa`` is dropped like ``N + alpha`` (docs/learner-math.md)."""
    kappa = model.params.sticky_kappa
    prev_ids = model._history.last_ids()  # chosen expert id of each particle
    is_new = flat_slots < 0
    ids = np.where(is_new, -2, model._ids[np.where(is_new, 0, flat_slots)])
    is_prev = ids == prev_ids[flat_part]
    if math.isinf(kappa):
        base[~is_prev] = -np.inf
    else:
        # the C library's log1p, as every log of the learning path (docs/reproducibility.md)
        base[is_prev] += [math.log1p(kappa / n) for n in model._npts[flat_slots[is_prev]].tolist()]


def gp_factors(model: Roger, xs: FloatArray, ys: FloatArray, live: IntArray, base: FloatArray,
                flat_slots: IntArray, ll_new: float, cap: int) -> tuple[FloatArray, SlotTerms]:
    """``log N(y; mu_s(x), s_s^2 I)`` per slot, ``-inf`` where provably negligible (the
    putatives' slots ``flat_slots``, ``-1`` a new expert, with their log weights before the
    GP factor ``base``)."""
    slot_ll = np.full(cap, -np.inf)
    terms: SlotTerms = {}
    if live.size == 0:
        return slot_ll, terms
    margin = model.params.prune_log_margin
    if math.isinf(margin):
        cand = live
        order: IntArray = cand
    else:
        # best (particle weight + CRP + gate) over the putatives of each slot
        is_new = flat_slots < 0
        best = np.full(cap, -np.inf)
        np.maximum.at(best, flat_slots[~is_new], base[~is_new])
        known = float(np.max(base[is_new])) + ll_new  # exact, from the empty expert
        upper = best[live] + model._gp_bound
        cand = live[upper >= known - margin]
        order = cand[np.argsort(-best[cand], kind="stable")]
    gps = model._gps

    p = model.params

    def evaluate(slots: IntArray) -> None:
        if slots.size == 0:
            return
        chosen = slots.tolist()
        got = evaluate_many([gps[s] for s in chosen], xs)
        terms.update((s, (got, j)) for j, s in enumerate(chosen))
        _jit.slot_log_likelihoods(slots, ys, got.means, got.latent, p.theta_n, model._ll_dims,
                                  slot_ll)

    if math.isinf(margin) or order.size <= _STAGE1:
        evaluate(order)
        return slot_ll, terms
    first, rest = order[:_STAGE1], order[_STAGE1:]
    evaluate(first)
    known = max(known, float(np.max(best[first] + slot_ll[first])))
    evaluate(rest[best[rest] + model._gp_bound >= known - margin])
    return slot_ll, terms


def instantiate(model: Roger, keep: IntArray, new_logw: FloatArray, flat_part: IntArray,
                 flat_slots: IntArray, offsets: IntArray, xs: FloatArray, ys: FloatArray,
                 terms: SlotTerms) -> float:
    """Build the surviving particles; update each chosen expert once (copy-on-write).

    Returns the smallest novelty-test margin of the updated experts (``inf``: none).
    """
    surv_parent = flat_part[keep]
    surv_slot = flat_slots[keep]
    surv_pos = keep - offsets[surv_parent]
    # how many survivors contain each slot, and how many of them chose it
    contains, chose, chosen = _jit.survivor_counts(model._slots, model._starts, surv_parent,
                                                   surv_slot, len(model._gps))
    sources: list[int] = []  # each chosen slot; upd_slots: the slot of its updated version
    new_target = -1
    pending: list[PendingCopy] = []  # copy-on-write copies to fill
    upd_gps: list[SparseOnlineGP] = []
    upd_evaluated: list[tuple[Evaluation, int] | None] = []  # where each one's terms are
    upd_slots: list[int] = []
    kept_old = (contains != chose).tolist()  # by slot: some survivor keeps the old version
    for s in chosen.tolist():
        if s < 0:  # a new expert, shared by every survivor that opened one this step
            t = new_target = model._alloc_slot()
            gp = model._new_gp()
            gp.update(xs, ys)
            model._gps[t] = gp
            model._gates.set_prior_updated(t, xs)
            model._ids[t] = model._next_id
            model._next_id += 1
            model._npts[t] = 1
            continue
        src = model._gps[s]
        assert src is not None
        if not kept_old[s]:  # nobody keeps the old version: update in place
            t, gp = s, src
        else:
            t = model._alloc_slot()
            gp = src.copy(model._pool, pending)
            model._gps[t] = gp
            model._gates.copy_slot(t, s)
            model._ids[t] = model._ids[s]
        upd_gps.append(gp)
        upd_evaluated.append(terms.get(s))
        upd_slots.append(t)
        sources.append(s)
    upd_arr = np.array(upd_slots, dtype=np.int64)
    src_arr = np.array(sources, dtype=np.int64)
    model._npts[upd_arr] = model._npts[src_arr] + 1  # each updated version's count
    copy_many(pending)  # the copies' matrices, several at once
    # incorporate the point: SOGP (§2.5, batched hot path) and NIW gate (§3.2)
    update_evaluated(upd_gps, xs, ys, upd_evaluated)
    if upd_slots:
        model._gates.update_many(upd_arr, xs)
    # the survivors, each chosen expert replaced by its updated version; the reference
    # counts; the slots no survivor holds, freed
    new_slots, new_starts, chosen_ids, new_ref, freed = _jit.survivor_particles(
        model._slots, model._starts, surv_parent, surv_slot, surv_pos, src_arr, upd_arr,
        new_target, model._ids, model._ref)
    for s in freed.tolist():
        dropped = model._gps[s]
        if dropped is not None:
            dropped.release(model._pool)  # its buffers serve later copies (.buffers)
        model._gps[s] = None
        model._ids[s] = -1
        model._npts[s] = 0
        model._free.append(s)
    model._free.sort(reverse=True)
    model._ref = new_ref
    model._slots, model._starts = new_slots, new_starts
    model._logw = new_logw
    model._history.append(surv_parent, chosen_ids)
    model.n_learned += 1
    return min((gp.novelty_margin for gp in upd_gps), default=math.inf)
