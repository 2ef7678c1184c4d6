"""ROGER's predictions (paper Algorithm 2, docs/learner-math.md §6).

The MAP particle's experts compete through their gates, ``p(k | x) ∝ n_k t_k(x)``;
:func:`predict` evaluates the gates once and the GPs it needs once, and returns the chosen
expert's prediction, the whole multimap, or both (one call per control tick).  They read a
model's store of experts (:class:`.engine.store.ExpertStore`) and its fixed terms
(:class:`.roger_terms.ModelTerms`), which :class:`.roger.Roger` hands them.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.prediction import ExpertPrediction, MultimapTable, Prediction
from roger_daemon.learner.roger_terms import Experts, ModelTerms
from roger_daemon.learner.scaling import as_vector
from roger_daemon.learner.sogp_batch import predict_many

__all__ = ["drop_unsupported", "gate_probs", "predict", "predict_table"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


def drop_unsupported(lg: FloatArray, npts: IntArray, support: int) -> None:
    """``lg[k] = -inf`` (in place) for the experts below ``support`` points: too small to
    compete, unless no expert has the support (``min_support``, docs/learner-math.md §6)."""
    if support > 1:
        small = npts < support
        if not small.all():
            lg[small] = -np.inf


def gate_probs(store: Experts, terms: ModelTerms, slots: IntArray, xs: FloatArray
               ) -> FloatArray:
    """``p(k | x) ∝ n_k t_k(x)`` over ``slots`` (+ ``alpha t_0(x)`` if the empty expert
    takes part), normalised (paper Algorithm 2, docs/learner-math.md §6)."""
    by_slot = np.empty(store.counts.size)
    store.gates.crp_log_terms(slots, xs, store.counts, by_slot)
    lg = by_slot[slots]
    npts = store.counts[slots]
    with_empty = terms.params.predict_empty_expert
    empty = terms.log_alpha + store.gates.prior_log_predictive(xs) if with_empty else -np.inf
    if not max(lg.max(), empty) > -np.inf:
        # x so far from every gate that each density underflows: the gates cannot tell the
        # experts apart, p(k | x) ∝ n_k (the CRP prior alone, docs/learner-math.md §6)
        lg = np.log(npts.astype(np.float64))
        empty = terms.log_alpha
    drop_unsupported(lg, npts, terms.params.min_support)
    if with_empty:
        lg = np.append(lg, empty)
    w = np.exp(lg - lg.max())  # the methods: numpy's reductions without their wrappers
    out: FloatArray = w / w.sum()
    return out


def _prior(terms: ModelTerms, gate_prob: float) -> Prediction:
    s = terms.scaling
    return Prediction(mean=s.mean_out(np.zeros(terms.d_y)), var=s.var_out(terms.empty_var),
                      expert_id=-1, gate_prob=gate_prob)


def _choose(terms: ModelTerms, probs: FloatArray, rng: np.random.Generator) -> int:
    """Index of the expert ``predict_one`` answers with (argmax, or one draw from ``rng``)."""
    if terms.params.expert_choice == "argmax":
        return int(probs.argmax())
    return min(int(np.searchsorted(np.cumsum(probs), rng.random(), side="right")),
               probs.size - 1)


def _expert(store: Experts, terms: ModelTerms, slot: int, xs: FloatArray, prob: float
            ) -> ExpertPrediction:
    mean, var = store.expert(slot).predict(xs)
    sc = terms.scaling
    return ExpertPrediction(expert_id=int(store.ids[slot]), gate_prob=prob,
                            mean=sc.mean_out(mean), var=sc.var_out(var),
                            n_points=int(store.counts[slot]))


def _branches(store: Experts, terms: ModelTerms, slots: IntArray, xs: FloatArray,
              probs: FloatArray) -> MultimapTable:
    """The multimap's rows over ``slots`` (+ the empty expert's if it takes part): the GPs
    evaluated several per compiled call (:func:`.sogp_batch.predict_many`), the scaling back
    to output units done once for all of them (the same floats as each expert's own
    :func:`_expert`: it is elementwise)."""
    sl = slots.tolist()
    means = np.empty((len(sl), terms.d_y))
    variance = np.empty(len(sl))  # predictive, model units (observation noise included)
    predict_many(store.experts(sl), xs, means, variance)
    sc = terms.scaling
    means = sc.mean_out(means)
    var = sc.var_out(variance[:, None])  # type: ignore[arg-type]  # a column: one per expert
    ids = store.ids[sl].tolist()
    npts = store.counts[sl].tolist()
    gate = probs.tolist()
    if terms.params.predict_empty_expert:  # its row last, its gate probability last
        prior = _prior(terms, gate[-1])
        means = np.vstack([means, prior.mean])
        var = np.vstack([var, prior.var])
        ids.append(-1)
        npts.append(0)
    return MultimapTable(ids, gate, means, var, npts)


def predict_table(store: Experts, terms: ModelTerms, x: npt.ArrayLike, rng: np.random.Generator,
                  *, one: bool = True) -> tuple[Prediction | None, MultimapTable]:
    """``predict_one``'s answer for ``x`` (if ``one``; a draw from ``rng`` with
    ``expert_choice="sample"``) and the whole multimap as a table: the gates evaluated once,
    every expert's GP once; the chosen expert's answer is its row.  Identical, float for float
    and draw for draw, to calling ``predict_one`` then ``predict_multimap``."""
    xs = terms.scaling.x_in(as_vector("x", x, terms.d_x))
    slots = store.particle(store.map_particle())
    if slots.size == 0:
        prior = _prior(terms, 1.0)
        table = MultimapTable([-1], [1.0], prior.mean[None, :], prior.var[None, :], [0]) \
            if terms.params.predict_empty_expert else MultimapTable.empty(terms.d_y)
        return (prior if one else None), table
    probs = gate_probs(store, terms, slots, xs)
    table = _branches(store, terms, slots, xs, probs)
    return (table.prediction(_choose(terms, probs, rng)) if one else None), table


def predict(store: Experts, terms: ModelTerms, x: npt.ArrayLike, rng: np.random.Generator, *,
            one: bool, multimap: bool
            ) -> tuple[Prediction | None, list[ExpertPrediction] | None]:
    """``(predict_one, predict_multimap)`` answers for ``x``, each only if asked for.

    The gates are evaluated once; with ``multimap`` every expert's GP once
    (:func:`predict_table`), else only the chosen expert's.  Identical, float for float
    and draw for draw, to calling ``predict_one`` then ``predict_multimap``.
    """
    if multimap:
        pred, table = predict_table(store, terms, x, rng, one=one)
        return pred, table.experts()
    xs = terms.scaling.x_in(as_vector("x", x, terms.d_x))
    slots = store.particle(store.map_particle())
    if slots.size == 0:
        return (_prior(terms, 1.0) if one else None), None
    if not one:
        return None, None
    probs = gate_probs(store, terms, slots, xs)
    k = _choose(terms, probs, rng)
    if k == slots.size:  # the empty expert
        return _prior(terms, float(probs[k])), None
    e = _expert(store, terms, int(slots[k]), xs, float(probs[k]))
    return Prediction(mean=e.mean, var=e.var, expert_id=e.expert_id,
                      gate_prob=e.gate_prob), None
