"""One ROGER learning step (paper Algorithm 1, docs/learner-math.md §4).

:func:`putatives` computes the log weight of every putative (each particle's experts plus one
new empty expert) from predictive quantities only, touching no expert; after resampling,
:func:`instantiate` builds the survivors and incorporates the point into each chosen expert
once (copy-on-write of the slots shared with survivors that keep the old version,
:class:`.engine.store.ExpertStore`).  Both work on a model's store of experts, its fixed terms
(:class:`.roger_terms.ModelTerms`) and its segmentation history, which :class:`.roger.Roger`
hands them.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.engine import jit as _jit
from roger_daemon.learner.history import SegmentationHistory
from roger_daemon.learner.roger_terms import Experts, ModelTerms
from roger_daemon.learner.sogp import SparseOnlineGP
from roger_daemon.learner.sogp_batch import Evaluation, evaluate_many, update_evaluated

__all__ = ["Putatives", "SlotTerms", "instantiate", "putatives"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
#: the step's evaluated experts by slot: where each one's terms are (an update reuses its
#: expert's, built only then: :meth:`.sogp_batch.Evaluation.terms`)
SlotTerms = dict[int, tuple[Evaluation, int]]

_STAGE1 = 4  # experts evaluated first to sharpen the pruning bound


class Putatives(NamedTuple):
    """A step's putatives: putative ``j`` puts the point into expert slot ``slot[j]`` (``-1``:
    a new one) of particle ``parent[j]``, with log weight ``log_weights[j]``; particle ``p``'s
    putatives start at ``offsets[p]``; ``terms``, the evaluated experts' terms by slot."""

    log_weights: FloatArray
    parent: IntArray
    slot: IntArray
    offsets: IntArray
    terms: SlotTerms


def putatives(store: Experts, terms: ModelTerms, history: SegmentationHistory, xs: FloatArray,
              ys: FloatArray) -> Putatives:
    """Log weights of all putatives (Algorithm 1, inner loops), touching no expert: particle
    weight + CRP prior + gate + GP likelihood of the point, in model units."""
    cap = store.capacity
    # gates of all unique experts, batched (§3.4); CRP prior n_k (N + alpha dropped, §4)
    live = store.live()
    slot_gate = np.zeros(cap)
    store.gates.crp_log_terms(live, xs, store.counts, slot_gate)
    # each particle's putatives: its experts, then the new one (:mod:`.engine.jit_layout`)
    flat_slots, flat_part, offsets, base = _jit.putative_layout(
        store.slots, store.starts, store.log_weights, slot_gate,
        terms.log_alpha + store.gates.prior_log_predictive(xs))
    if terms.params.sticky_kappa > 0.0 and len(history) > 0:
        add_stickiness(store, terms.params.sticky_kappa, history, base, flat_part, flat_slots)

    # GP factor: the empty expert analytically, the others once per unique expert
    yy = _jit.dot_column(ys, ys.reshape(-1, 1), 0, terms.d_y)  # |y|^2 in index order, no BLAS
    ll_new = _jit.gaussian_log_density(yy, terms.empty_var, terms.ll_dims)
    slot_ll, evaluated = gp_factors(store, terms, xs, ys, live, base, flat_slots, ll_new)
    lw = _jit.putative_log_weights(base, flat_slots, slot_ll, ll_new)
    return Putatives(lw, flat_part, flat_slots, offsets, evaluated)


def add_stickiness(store: Experts, kappa: float, history: SegmentationHistory,
                   base: FloatArray, flat_part: IntArray, flat_slots: IntArray) -> None:
    """Sticky CRP (Fox et al. 2008; paper section V): the expert of the previous point in
    each particle weighs ``n_k + kappa`` instead of ``n_k``; with ``kappa = inf`` every
    other putative of that particle gets weight 0.  The common normaliser
    ``N + alpha + kappa`` is dropped like ``N + alpha`` (docs/learner-math.md)."""
    prev_ids = history.last_ids()  # chosen expert id of each particle
    is_new = flat_slots < 0
    ids = np.where(is_new, -2, store.ids[np.where(is_new, 0, flat_slots)])
    is_prev = ids == prev_ids[flat_part]
    if math.isinf(kappa):
        base[~is_prev] = -np.inf
    else:
        # the C library's log1p, as every log of the learning path (docs/reproducibility.md)
        base[is_prev] += [math.log1p(kappa / n)
                          for n in store.counts[flat_slots[is_prev]].tolist()]


def gp_factors(store: Experts, terms: ModelTerms, xs: FloatArray, ys: FloatArray,
               live: IntArray, base: FloatArray, flat_slots: IntArray, ll_new: float
               ) -> tuple[FloatArray, SlotTerms]:
    """``log N(y; mu_s(x), s_s^2 I)`` per slot, ``-inf`` where provably negligible (the
    putatives' slots ``flat_slots``, ``-1`` a new expert, with their log weights before the
    GP factor ``base``)."""
    cap = store.capacity
    slot_ll = np.full(cap, -np.inf)
    evaluated: SlotTerms = {}
    if live.size == 0:
        return slot_ll, evaluated
    margin = terms.params.prune_log_margin

    def evaluate(slots: IntArray) -> None:
        if slots.size == 0:
            return
        chosen = slots.tolist()
        got = evaluate_many(store.experts(chosen), xs)
        evaluated.update((s, (got, j)) for j, s in enumerate(chosen))
        _jit.slot_log_likelihoods(slots, ys, got.means, got.latent, terms.params.theta_n,
                                  terms.ll_dims, slot_ll)

    if math.isinf(margin):
        evaluate(live)
        return slot_ll, evaluated
    # best (particle weight + CRP + gate) over the putatives of each slot
    is_new = flat_slots < 0
    best = np.full(cap, -np.inf)
    np.maximum.at(best, flat_slots[~is_new], base[~is_new])
    known = float(np.max(base[is_new])) + ll_new  # exact, from the empty expert
    cand = live[best[live] + terms.gp_bound >= known - margin]
    order = cand[np.argsort(-best[cand], kind="stable")]
    if order.size <= _STAGE1:
        evaluate(order)
        return slot_ll, evaluated
    first, rest = order[:_STAGE1], order[_STAGE1:]
    evaluate(first)
    known = max(known, float(np.max(best[first] + slot_ll[first])))
    evaluate(rest[best[rest] + terms.gp_bound >= known - margin])
    return slot_ll, evaluated


def instantiate(store: Experts, put: Putatives, keep: IntArray, new_logw: FloatArray,
                xs: FloatArray, ys: FloatArray) -> tuple[IntArray, float]:
    """Build the surviving putatives ``keep`` (log weights ``new_logw``) as the particles;
    update each chosen expert once (copy-on-write), its SOGP (§2.5) and its NIW gate (§3.2).

    Returns each survivor's chosen expert id and the smallest novelty-test margin of the
    updated experts (``inf``: none).
    """
    surv_parent = put.parent[keep]
    surv_slot = put.slot[keep]
    surv_pos = keep - put.offsets[surv_parent]
    shared, chosen = store.survivor_counts(surv_parent, surv_slot)
    new_slot = -1
    sources: list[int] = []  # each chosen slot; targets: the slot of its updated version
    targets: list[int] = []
    updated: list[SparseOnlineGP] = []
    evaluated: list[tuple[Evaluation, int] | None] = []  # where each one's terms are
    for s in chosen.tolist():
        if s < 0:  # a new expert, shared by every survivor that opened one this step
            new_slot, gp = store.open(xs)
            gp.update(xs, ys)
            continue
        t, gp = store.writable(s, shared[s])
        updated.append(gp)
        evaluated.append(put.terms.get(s))
        targets.append(t)
        sources.append(s)
    target_arr = np.array(targets, dtype=np.int64)
    store.finish_copies()  # the copies' matrices, several at once
    # incorporate the point: SOGP (§2.5, batched hot path) and NIW gate (§3.2)
    update_evaluated(updated, xs, ys, evaluated)
    if targets:
        store.gates.update_many(target_arr, xs)
    ids = store.advance(surv_parent, surv_slot, surv_pos, np.array(sources, dtype=np.int64),
                        target_arr, new_slot, new_logw)
    return ids, min((gp.novelty_margin for gp in updated), default=math.inf)
