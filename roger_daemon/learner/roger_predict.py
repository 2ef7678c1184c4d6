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

from roger_daemon.learner.prediction import ExpertPrediction, Prediction
from roger_daemon.learner.scaling import as_vector
from roger_daemon.learner.sogp_batch import predict_many

if TYPE_CHECKING:
    from roger_daemon.learner.roger import Roger

__all__ = ["gate_probs", "map_slots", "predict"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


def map_slots(model: Roger) -> IntArray:
    """Slots of the MAP particle (highest weight after the last resampling, §6)."""
    return model._particles[int(np.argmax(model._logw))]


def gate_probs(model: Roger, slots: IntArray, xs: FloatArray) -> FloatArray:
    """``p(k | x) ∝ n_k t_k(x)`` over ``slots`` (+ ``alpha t_0(x)`` if the empty expert
    takes part), normalised (paper Algorithm 2, docs/learner-math.md §6)."""
    npts = model._npts[slots]
    lg = model._gates.log_predictive(slots, xs) + np.log(npts)
    support = model.params.min_support
    if support > 1:  # too small to compete, unless no expert has the support
        small = npts < support
        if not small.all():
            lg[small] = -np.inf
    if model.params.predict_empty_expert:
        lg = np.append(lg, model._log_alpha + model._gates.prior_log_predictive(xs))
    w = np.exp(lg - np.max(lg))
    out: FloatArray = w / np.sum(w)
    return out


def _prior(model: Roger, gate_prob: float) -> Prediction:
    s = model._scaling
    return Prediction(mean=s.mean_out(np.zeros(model.d_y)), var=s.var_out(model._empty_var),
                      expert_id=-1, gate_prob=gate_prob)


def _choose(model: Roger, probs: FloatArray, rng: np.random.Generator | None) -> int:
    """Index of the expert ``predict_one`` answers with (argmax, or one draw)."""
    if model.params.expert_choice == "argmax":
        return int(np.argmax(probs))
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


def _experts(model: Roger, slots: list[int], xs: FloatArray, probs: FloatArray
             ) -> list[ExpertPrediction]:
    """``[_expert(model, s, xs, p) ...]`` over ``slots``: the GPs evaluated several per compiled
    call (:func:`.sogp_batch.predict_many`), the scaling back to output units done once for
    all of them (the same floats: it is elementwise)."""
    gps = [model._gps[s] for s in slots]
    means = np.empty((len(slots), model.d_y))
    variance = np.empty(len(slots))  # predictive, model units (observation noise included)
    predict_many(gps, xs, means, variance)  # type: ignore[arg-type]  # live slots: no None
    sc = model._scaling
    means = sc.mean_out(means)
    var = sc.var_out(variance[:, None])  # type: ignore[arg-type]  # a column: one per expert
    ids = model._ids[slots].tolist()
    npts = model._npts[slots].tolist()
    gate = probs.tolist()
    return [ExpertPrediction(expert_id=ids[j], gate_prob=gate[j], mean=means[j], var=var[j],
                             n_points=npts[j]) for j in range(len(slots))]


def predict(model: Roger, x: npt.ArrayLike, *, one: bool, multimap: bool,
            rng: np.random.Generator | None = None
            ) -> tuple[Prediction | None, list[ExpertPrediction] | None]:
    """``(predict_one, predict_multimap)`` answers for ``x``, each only if asked for.

    The gates are evaluated once; with ``multimap`` every expert's GP once (the chosen
    expert's answer is its entry), else only the chosen expert's.  Identical, float for float
    and draw for draw, to calling ``predict_one`` then ``predict_multimap``.
    """
    xs = model._scaling.x_in(as_vector("x", x, model.d_x))
    slots = map_slots(model)
    empty = model.params.predict_empty_expert
    if slots.size == 0:
        prior = _prior(model, 1.0)
        mm = [ExpertPrediction(expert_id=-1, gate_prob=1.0, mean=prior.mean, var=prior.var,
                               n_points=0)] if empty else []
        return (prior if one else None), (mm if multimap else None)
    probs = gate_probs(model, slots, xs)
    k = _choose(model, probs, rng) if one else -1
    experts: list[ExpertPrediction] = []
    if multimap:
        experts = _experts(model, slots.tolist(), xs, probs)
        if empty:
            prior = _prior(model, float(probs[-1]))
            experts.append(ExpertPrediction(expert_id=-1, gate_prob=prior.gate_prob,
                                            mean=prior.mean, var=prior.var, n_points=0))
    pred: Prediction | None = None
    if one and k == slots.size:  # the empty expert
        pred = _prior(model, float(probs[k]))
    elif one:
        e = experts[k] if multimap else _expert(model, int(slots[k]), xs, float(probs[k]))
        pred = Prediction(mean=e.mean, var=e.var, expert_id=e.expert_id,
                          gate_prob=e.gate_prob)
    return pred, (experts if multimap else None)
