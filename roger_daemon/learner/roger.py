"""ROGER: an infinite mixture of sparse online GP experts, tracked by a particle filter.

Grollman & Jenkins (IROS 2010), section III: each expert is an NIW input gate
(:mod:`.gate`) plus a sparse online GP (:mod:`.sogp`); a particle is one partition of the data
into experts under a CRP prior; ``P`` particles are carried by Fearnhead's optimal resampling
(:mod:`.resampling`).

Algorithm 1 (``learn_one``), docs/learner-math.md §4:

1. for every particle ``p`` and every expert ``k`` of it, plus one new empty expert, the
   putative log weight is ``log w_p + log CRP(k) + log t_k(x) + log N(y; mu_k(x), s_k^2 I)``,
   computed from predictive quantities only (no expert is touched);
2. resample the putatives to ``P`` survivors;
3. only then incorporate ``(x, y)`` into the chosen expert of each survivor.

Performance design (pitfalls 13-15 of docs/learner-math.md §7): experts live in integer *slots*
shared by all particles that contain them (a particle is a run of slots in one flat int array,
:class:`.engine.store.ExpertStore`); a slot is copied only when a survivor updates an expert
that another survivor keeps unchanged (copy-on-write), and survivors that choose the same slot
share one updated copy.  Per step each *unique* expert is evaluated once (all gates in one
batched product, then each GP once, whatever the number of particles that share it), and the
chosen experts are updated together (:func:`.sogp_batch.update_evaluated`), so the cost is
bounded by (unique experts) x ``beta^2``, never by the data seen.  An opt-in bound
(``prune_log_margin``) skips the GP of experts whose putatives cannot carry weight.  The
segmentation history costs O(P) per step: survivors' ancestor index and chosen expert id,
traced back by :meth:`Roger.assignments`, collapsed to one id per point once the particles'
lineages meet (:mod:`.history`).

The step itself is in :mod:`.roger_step`, the predictions in :mod:`.roger_predict`, the
model's fixed terms in :mod:`.roger_terms`; the compiled kernels and the store of experts they
work on are the engine's (:mod:`.engine`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.engine.store import ExpertStore
from roger_daemon.learner.history import SegmentationHistory
from roger_daemon.learner.model_args import Seed, resolve_model_args, spawn_generators
from roger_daemon.learner.params import RogerParams
from roger_daemon.learner.prediction import ExpertPrediction, MultimapTable, Prediction
from roger_daemon.learner.resampling import fearnhead_resample
from roger_daemon.learner.roger_predict import predict, predict_table
from roger_daemon.learner.roger_state import load_roger_arrays, roger_arrays
from roger_daemon.learner.roger_step import Putatives, instantiate, putatives
from roger_daemon.learner.roger_terms import Experts, ModelTerms
from roger_daemon.learner.scaling import as_vector
from roger_daemon.learner.sogp import SparseOnlineGP
from roger_daemon.learner.state import (
    generator_from_state,
    model_meta,
    unpack_meta,
)

__all__ = ["Roger"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


class Roger:
    """The ROGER multimap learner (paper Algorithms 1 and 2).

    Parameters
    ----------
    d_x, d_y : int
        Input and output dimensions.
    params : RogerParams, optional
        Hyperparameters; the paper's by default.
    seed : int, numpy Generator or None
        Source of randomness.  Two independent streams are spawned from it: one for learning
        (resampling) and one for prediction (expert sampling), so predictions never change
        what is learned.

    Examples
    --------
    >>> model = Roger(d_x=1, d_y=1, seed=0)
    >>> for i in range(200):
    ...     x = np.array([i % 20 / 20.0])
    ...     y = np.array([(-1.0) ** i * np.sqrt(x[0])])  # two interleaved branches
    ...     model.learn_one(x, y)
    >>> model.n_learned, model.n_experts >= 2
    (200, True)
    >>> means = sorted(float(e.mean[0]) for e in model.predict_multimap(np.array([0.5])))
    >>> min(abs(m - 0.707) for m in means) < 0.1, min(abs(m + 0.707) for m in means) < 0.1
    (True, True)

    Notes
    -----
    Cost per step: O(U d_x^2) for the gates of the U unique experts, O(U' (beta d_x + beta^2))
    for the U' <= U experts that survive pruning, and O(beta^2) for each of the at most ``P``
    experts updated.
    """

    kind = "roger"

    def __init__(self, d_x: int, d_y: int, params: RogerParams | None = None,
                 seed: Seed = None) -> None:
        self.d_x, self.d_y, self.params = resolve_model_args(d_x, d_y, params)
        self._learn_rng, self._predict_rng = spawn_generators(seed)
        #: the model's parameters, scaling, kernel and the constants of its putatives
        self.terms = ModelTerms.of(self.d_x, self.d_y, self.params)
        self.kernel = self.terms.kernel
        self._store: Experts = ExpertStore(self.terms.new_gates(), self.terms.new_expert,
                                           pool_limit=self.params.particles)
        self._history = SegmentationHistory(self.params.particles)
        self.n_learned = 0
        # how close the last learn_one's discrete decisions were to flipping (diagnostic, not
        # state): resampling in normalised weight, novelty in units of k* (docs/reproducibility.md)
        self._margins: tuple[Any, float] | None = None  # (resampling margin or its thunk, novelty)
        self._margins_read: dict[str, float] = {}

    @property
    def store(self) -> Experts:
        """The experts of every particle, in slots (:class:`.engine.store.ExpertStore`): for
        inspection, tests and diagnostics; learning goes through :meth:`learn_one`."""
        return self._store

    @property
    def history(self) -> SegmentationHistory:
        """Each step's (ancestor, chosen expert) of every survivor (:mod:`.history`)."""
        return self._history

    # -- Algorithm 1: learning -------------------------------------------------------------------

    def learn_one(self, x: npt.ArrayLike, y: npt.ArrayLike) -> None:
        """Learn one (perception, action) pair (paper Algorithm 1).

        Raises ``ValueError`` (model unchanged) if ``x`` or ``y`` has the wrong shape or is not
        finite.
        """
        xs, ys = self._in_model_units(x, y)
        # every putative's weight from predictive quantities only (Algorithm 1, inner loops)
        put = putatives(self._store, self.terms, self._history, xs, ys)
        # resample to P (Fearnhead), then incorporate the point (Algorithm 1, last two lines)
        resampled: dict[str, Any] = {}
        keep, new_logw = fearnhead_resample(put.log_weights, self.params.particles,
                                            self._learn_rng, resampled, lazy=True)
        novelty = self._incorporate(put, keep, new_logw, xs, ys)
        self._margins = (resampled["margin"], novelty)
        self._margins_read = {}

    def learn_assigned(self, x: npt.ArrayLike, y: npt.ArrayLike, expert_id: int | None) -> int:
        """Algorithm 1's last step with the choice given, not sampled (a model of one
        particle: :func:`.partition.fit_partition`): the pair joins expert ``expert_id`` of the
        particle, or a new expert (``None``), exactly as when resampling chose that putative.
        Returns the expert's id."""
        if self.n_particles != 1:
            raise ValueError(f"learn_assigned needs a model of one particle, "
                             f"not {self.n_particles}")
        xs, ys = self._in_model_units(x, y)
        put = putatives(self._store, self.terms, self._history, xs, ys)
        target = -1 if expert_id is None else next(
            (s for s in self._store.particle(0).tolist() if self._store.ids[s] == expert_id),
            None)
        if target is None:
            raise ValueError(f"the particle has no expert {expert_id}")
        j = int(np.flatnonzero(put.slot == target)[0])
        self._incorporate(put, np.array([j]), np.zeros(1), xs, ys)
        return int(self._history.last_ids()[0])

    def _in_model_units(self, x: npt.ArrayLike, y: npt.ArrayLike
                        ) -> tuple[FloatArray, FloatArray]:
        scaling = self.terms.scaling
        return (scaling.x_in(as_vector("x", x, self.d_x)),
                scaling.y_in(as_vector("y", y, self.d_y)))

    def _incorporate(self, put: Putatives, keep: IntArray, new_logw: FloatArray,
                     xs: FloatArray, ys: FloatArray) -> float:
        """The survivors ``keep`` of the putatives become the particles, each chosen expert
        updated once (:func:`.roger_step.instantiate`), the choices recorded; returns the
        smallest novelty margin of the updated experts."""
        ids, novelty = instantiate(self._store, put, keep, new_logw, xs, ys)
        self._history.append(put.parent[keep], ids)
        self.n_learned += 1
        return novelty

    @property
    def last_margins(self) -> dict[str, float]:
        """How close the last ``learn_one``'s discrete decisions were to flipping (diagnostic,
        not state): ``"resampling"`` in normalised weight, ``"novelty"`` in units of ``k*``
        (docs/reproducibility.md); ``{}`` before any learning.  Computed when first read."""
        if self._margins is not None and not self._margins_read:
            margin, novelty = self._margins
            self._margins_read = {"resampling": float(margin() if callable(margin) else margin),
                                  "novelty": novelty}
        return self._margins_read

    # -- Algorithm 2: prediction (:mod:`.roger_predict`) ------------------------------------------

    def _rng(self, rng: np.random.Generator | None) -> np.random.Generator:
        return self._predict_rng if rng is None else rng

    def predict_one(self, x: npt.ArrayLike, *, rng: np.random.Generator | None = None
                    ) -> Prediction:
        """Predict the action for ``x`` (paper Algorithm 2).

        The expert of the MAP particle is chosen by gate probability: the most probable one
        (``expert_choice="argmax"``) or a draw (``"sample"``, from the model's prediction
        stream, or from ``rng`` if given).  Before any learning: the prior, ``expert_id = -1``.
        """
        pred, _ = predict(self._store, self.terms, x, self._rng(rng), one=True, multimap=False)
        assert pred is not None
        return pred

    def predict_multimap(self, x: npt.ArrayLike) -> list[ExpertPrediction]:
        """Every expert of the MAP particle: gate probability (summing to 1), mean, variance."""
        _, mm = predict(self._store, self.terms, x, self._predict_rng, one=False, multimap=True)
        assert mm is not None
        return mm

    def predict_with_multimap(self, x: npt.ArrayLike, *, rng: np.random.Generator | None = None
                              ) -> tuple[Prediction, list[ExpertPrediction]]:
        """``(predict_one(x), predict_multimap(x))`` in one pass: the gates and every expert's
        GP evaluated once (one call per control tick); the same floats and draws as the two
        calls."""
        pred, mm = predict(self._store, self.terms, x, self._rng(rng), one=True, multimap=True)
        assert pred is not None and mm is not None
        return pred, mm

    def predict_table(self, x: npt.ArrayLike, *, rng: np.random.Generator | None = None
                      ) -> tuple[Prediction, MultimapTable]:
        """``predict_with_multimap(x)`` with the multimap as a table of arrays (one row per
        expert, the same floats and draws), without an object per expert: what a daemon
        builds its reply from."""
        pred, table = predict_table(self._store, self.terms, x, self._rng(rng))
        assert pred is not None
        return pred, table

    # -- segmentation and introspection --------------------------------------------------------

    def _map_slots(self) -> IntArray:
        return self._store.particle(self._store.map_particle())

    @property
    def n_experts(self) -> int:
        """Number of experts in the MAP particle."""
        return int(self._map_slots().size)

    @property
    def n_particles(self) -> int:
        """Particles currently carried (``P`` once there are enough putatives)."""
        return self._store.n_particles

    def particle_slots(self, p: int) -> IntArray:
        """The expert slots of particle ``p``, in order (a copy)."""
        return self._store.particle(p)

    @property
    def n_unique_experts(self) -> int:
        """Distinct expert versions held by all particles together (memory in use)."""
        return int(np.count_nonzero(self._store.ref))

    def particle_log_weights(self) -> FloatArray:
        """Normalised log weights of the particles."""
        return self._store.log_weights.copy()

    def expert_sizes(self) -> dict[int, int]:
        """``{expert_id: points assigned}`` in the MAP particle."""
        store = self._store
        return {int(store.ids[s]): int(store.counts[s]) for s in self._map_slots().tolist()}

    def basis_sizes(self) -> dict[int, int]:
        """``{expert_id: basis vectors}`` in the MAP particle (each <= ``beta``)."""
        store = self._store
        return {int(store.ids[s]): store.expert(s).n for s in self._map_slots().tolist()}

    def assignments(self) -> IntArray:
        """The MAP particle's expert id for every learned point, in order.

        The settled points read as is, the last few steps traced back through the stored
        (ancestor, chosen expert) (:mod:`.history`): O(N) per call, 8 bytes per point of memory
        plus ``8 (P + 1)`` per point on which the particles' lineages still disagree.
        """
        if self.n_learned == 0:
            return np.zeros(0, dtype=np.int64)
        return self._history.assignments(self._store.map_particle())

    def unsettled_points(self) -> IntArray:
        """The learned points whose expert further learning may still change, ascending: those
        on which the particles' lineages disagree and the last few steps (:mod:`.history`).
        Every other point has the same expert in every particle, for good."""
        return self._history.unsettled_points()

    def assignments_at(self, points: npt.ArrayLike) -> IntArray:
        """``assignments()[points]`` in O(len(points)) plus the unsettled points (the daemon
        labels experts incrementally, :mod:`roger_daemon.labels`)."""
        if self.n_learned == 0:
            return self.assignments()[np.asarray(points, dtype=np.int64)]
        return self._history.assignments_at(self._store.map_particle(), points)

    def distinct_experts(self) -> list[SparseOnlineGP]:
        """The distinct SOGPs held by the particles (for inspection and tests)."""
        return self._store.distinct()

    # -- state ----------------------------------------------------------------------------------

    def state_dict(self) -> dict[str, np.ndarray]:
        """Flat named arrays plus JSON metadata; see :mod:`.state`.  No object arrays."""
        out = roger_arrays(self._store, self._history, self.terms)
        out["meta"] = model_meta(self.kind, self.d_x, self.d_y, self.params.to_mapping(),
                                 (self._learn_rng, self._predict_rng),
                                 n_learned=self.n_learned, next_expert_id=self._store.next_id)
        return out

    @classmethod
    def from_state_dict(cls, state: Mapping[str, np.ndarray]) -> Roger:
        """Rebuild a model that continues exactly as the saved one would.

        ``state`` is :meth:`state_dict` output or what ``np.load`` returns for it.
        """
        state = {k: np.asarray(state[k]) for k in state}
        meta = unpack_meta(state, cls.kind)
        params = RogerParams.from_mapping(meta["params"])
        model = cls(int(meta["d_x"]), int(meta["d_y"]), params)
        model._load(state, meta)
        return model

    def _load(self, state: dict[str, np.ndarray], meta: dict[str, Any]) -> None:
        """Set this freshly built model to the saved ``state`` (:func:`.roger_state
        .load_roger_arrays`) and ``meta``'s generators and counters."""
        self._learn_rng = generator_from_state(meta["rng_learn"])
        self._predict_rng = generator_from_state(meta["rng_predict"])
        self._history = load_roger_arrays(self._store, self.terms, state,
                                          int(meta["next_expert_id"]))
        self.n_learned = int(meta["n_learned"])
