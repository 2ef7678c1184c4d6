"""ROGER's predictions (paper Algorithm 2, docs/learner-math.md §6), on a :class:`.Roger`.

The MAP particle's experts compete through their gates, ``p(k | x) ∝ n_k t_k(x)``;
:func:`predict` evaluates the gates once and the GPs it needs once, and returns the chosen
expert's prediction, the whole multimap, or both (one call per control tick).  Split from
:mod:`.roger`, whose private state these functions read.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.prediction import ExpertPrediction, MultimapTable, Prediction
from roger_daemon.learner.scaling import as_vector
from roger_daemon.learner.sogp_batch import predict_many

if TYPE_CHECKING:
    from roger_daemon.learner.roger import Roger

__all__ = ["gate_probs", "map_slots", "predict", "predict_table"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


def map_slots(model: Roger) -> IntArray:
    """Slots of the MAP particle (highest weight after the last resampling, §6)."""
    return model.particle_slots(int(model._logw.argmax()))


def gate_probs(model: Roger, slots: IntArray, xs: FloatArray) -> FloatArray:
    """``p(k | x) ∝ n_k t_k(x)`` over ``slots`` (+ ``alpha t_0(x)`` if the empty expert
    takes part), normalised (paper Algorithm 2, docs/learner-math.md §6)."""
    by_slot = np.empty(model._npts.size)
    model._gates.crp_log_terms(slots, xs, model._npts, by_slot)
    lg = by_slot[slots]
    npts = model._npts[slots]
    support = model.params.min_support
    if support > 1:  # too small to compete, unless no expert has the support
        small = npts < support
        if not small.all():
            lg[small] = -np.inf
    if model.params.predict_empty_expert:
        lg = np.append(lg, model._log_alpha + model._gates.prior_log_predictive(xs))
    w = np.exp(lg - lg.max())  # the methods: numpy's reductions without their wrappers
    out: FloatArray = w / w.sum()
    return out


def _prior(model: Roger, gate_prob: float) -> Prediction:
    s = model._scaling
    return Prediction(mean=s.mean_out(np.zeros(model.d_y)), var=s.var_out(model._empty_var),
                      expert_id=-1, gate_prob=gate_prob)


def _choose(model: Roger, probs: FloatArray, rng: np.random.Generator | None) -> int:
    """Index of the expert ``predict_one`` answers with (argmax, or one draw)."""
    if model.params.expert_choice == "argmax":
        return int(probs.argmax())
    gen = model._predict_rng if rng is None else rng
    return min(int(np.searchsorted(np.cumsum(probs), gen.random(), side="right")),
               probs.size - 1)


def _expert(model: Roger, slot: int, xs: FloatArray, prob: float) -> ExpertPrediction:
    gp = model._gps[slot]
    assert gp is not None
    mean, var = gp.predict(xs)
    sc = model._scaling
    return ExpertPrediction(expert_id=int(model._ids[slot]), gate_prob=prob,
                            mean=sc.mean_out(mean), var=sc.var_out(var),
                            n_points=int(model._npts[slot]))


def _branches(model: Roger, slots: IntArray, xs: FloatArray, probs: FloatArray
              ) -> MultimapTable:
    """The multimap's rows over ``slots`` (+ the empty expert's if it takes part): the GPs
    evaluated several per compiled call (:func:`.sogp_batch.predict_many`), the scaling back
    to output units done once for all of them (the same floats as each expert's own
    :func:`_expert`: it is elementwise)."""
    sl = slots.tolist()
    gps = [model._gps[s] for s in sl]
    means = np.empty((len(sl), model.d_y))
    variance = np.empty(len(sl))  # predictive, model units (observation noise included)
    predict_many(gps, xs, means, variance)
    sc = model._scaling
    means = sc.mean_out(means)
    var = sc.var_out(variance[:, None])  # type: ignore[arg-type]  # a column: one per expert
    ids = model._ids[sl].tolist()
    npts = model._npts[sl].tolist()
    gate = probs.tolist()
    if model.params.predict_empty_expert:  # its row last, its gate probability last
        prior = _prior(model, gate[-1])
        means = np.vstack([means, prior.mean])
        var = np.vstack([var, prior.var])
        ids.append(-1)
        npts.append(0)
    return MultimapTable(ids, gate, means, var, npts)


def predict_table(model: Roger, x: npt.ArrayLike, *, one: bool = True,
                  rng: np.random.Generator | None = None
                  ) -> tuple[Prediction | None, MultimapTable]:
    """``predict_one``'s answer for ``x`` (if ``one``) and the whole multimap as a table:
    the gates evaluated once, every expert's GP once; the chosen expert's answer is its row.
    Identical, float for float and draw for draw, to calling ``predict_one`` then
    ``predict_multimap``."""
    xs = model._scaling.x_in(as_vector("x", x, model.d_x))
    slots = map_slots(model)
    if slots.size == 0:
        prior = _prior(model, 1.0)
        table = MultimapTable([-1], [1.0], prior.mean[None, :], prior.var[None, :], [0]) \
            if model.params.predict_empty_expert else MultimapTable.empty(model.d_y)
        return (prior if one else None), table
    probs = gate_probs(model, slots, xs)
    table = _branches(model, slots, xs, probs)
    return (table.prediction(_choose(model, probs, rng)) if one else None), table


def predict(model: Roger, x: npt.ArrayLike, *, one: bool, multimap: bool,
            rng: np.random.Generator | None = None
            ) -> tuple[Prediction | None, list[ExpertPrediction] | None]:
    """``(predict_one, predict_multimap)`` answers for ``x``, each only if asked for.

    The gates are evaluated once; with ``multimap`` every expert's GP once
    (:func:`predict_table`), else only the chosen expert's.  Identical, float for float
    and draw for draw, to calling ``predict_one`` then ``predict_multimap``.
    """
    if multimap:
        pred, table = predict_table(model, x, one=one, rng=rng)
        return pred, table.experts()
    xs = model._scaling.x_in(as_vector("x", x, model.d_x))
    slots = map_slots(model)
    if slots.size == 0:
        return (_prior(model, 1.0) if one else None), None
    if not one:
        return None, None
    probs = gate_probs(model, slots, xs)
    k = _choose(model, probs, rng)
    if k == slots.size:  # the empty expert
        return _prior(model, float(probs[k])), None
    e = _expert(model, int(slots[k]), xs, float(probs[k]))
    return Prediction(mean=e.mean, var=e.var, expert_id=e.expert_id,
                      gate_prob=e.gate_prob), None
