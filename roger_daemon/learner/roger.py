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

Performance design (pitfalls 13-15): experts live in integer *slots* shared by all particles
that contain them (a particle is a run of slots in one flat int array); a slot is copied only
when a survivor updates an expert that another survivor keeps unchanged (copy-on-write), and
survivors that choose the same slot share one updated copy.  Per step each *unique* expert is
evaluated once (all gates in one batched product, then each GP once, whatever the number of
particles that share it), and the chosen experts are updated together
(:func:`.sogp.update_many`), so the cost is bounded by (unique experts) x ``beta^2``, never
by the data seen.  An opt-in bound (``prune_log_margin``) skips the GP of experts whose
putatives cannot carry weight.  The segmentation history costs O(P) per step: survivors'
ancestor index and chosen expert id, traced back by :meth:`Roger.assignments`, collapsed to
one id per point once the particles' lineages meet (:mod:`.history`).

The step itself is in :mod:`.roger_step`, the predictions in :mod:`.roger_predict`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.engine.buffers import BufferPool
from roger_daemon.learner.engine.gates import GatePool
from roger_daemon.learner.history import SegmentationHistory
from roger_daemon.learner.kernel import RBFKernel
from roger_daemon.learner.params import RogerParams
from roger_daemon.learner.prediction import ExpertPrediction, MultimapTable, Prediction
from roger_daemon.learner.resampling import fearnhead_resample
from roger_daemon.learner.roger_predict import map_slots, predict, predict_table
from roger_daemon.learner.roger_state import load_roger_state, roger_state_dict
from roger_daemon.learner.roger_step import SlotTerms, instantiate, putatives
from roger_daemon.learner.scaling import AffineScaling, as_vector
from roger_daemon.learner.sogp import LATENT_FLOOR, SparseOnlineGP, likelihood_dims
from roger_daemon.learner.state import (
    Seed,
    spawn_generators,
    unpack_meta,
)

__all__ = ["Roger"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]



def check_dims(d_x: object, d_y: object) -> tuple[int, int]:
    """Validate the data dimensions (positive integers)."""
    for name, v in (("d_x", d_x), ("d_y", d_y)):
        if isinstance(v, bool) or not isinstance(v, int | np.integer) or int(v) < 1:
            raise ValueError(f"{name} must be an integer >= 1, got {v!r}")
    return int(d_x), int(d_y)  # type: ignore[call-overload]


def resolve_model_args(d_x: object, d_y: object, params: RogerParams | None
                       ) -> tuple[int, int, RogerParams]:
    """Validated ``(d_x, d_y, params)`` of a model constructor (paper defaults for ``None``)."""
    dx, dy = check_dims(d_x, d_y)
    resolved = RogerParams() if params is None else params
    if not isinstance(resolved, RogerParams):
        raise TypeError(f"params must be a RogerParams, got {type(params).__name__}")
    resolved.check_dims(dx, dy)
    return dx, dy, resolved


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
        self._setup()

    # -- construction ------------------------------------------------------------------------

    def _setup(self) -> None:
        p = self.params
        self._scaling = AffineScaling(p, self.d_x, self.d_y)
        self._dm = self._scaling.d_model  # input dimensions after input_weights
        self.kernel = RBFKernel(p.theta_w, self._dm, p.kernel_dim_scaling)
        self._gates = GatePool(self._dm, p.mu0, p.kappa0, p.lambda0, p.nu0)
        cap = self._gates.capacity
        self._gps: list[SparseOnlineGP | None] = [None] * cap
        self._ids = np.full(cap, -1, dtype=np.int64)
        self._npts = np.zeros(cap, dtype=np.int64)
        self._ref = np.zeros(cap, dtype=np.int64)
        self._free: list[int] = list(range(cap - 1, -1, -1))  # pop() yields the lowest slot
        # dropped experts' slabs (.jit_slab), reused by copy-on-write copies (not state): those
        # of at most as many experts as there are particles
        self._pool = BufferPool(limit=p.particles)
        # the particles, flat: particle p holds the expert slots _slots[_starts[p]:_starts[p + 1]]
        # (one array for all, so a step's bookkeeping is one compiled call: :mod:`.jit_layout`)
        self._slots = np.zeros(0, dtype=np.int64)
        self._starts = np.zeros(2, dtype=np.int64)
        self._logw = np.zeros(1)
        self._history = SegmentationHistory(p.particles)
        self.n_learned = 0
        # how close the last learn_one's discrete decisions were to flipping (diagnostic, not
        # state): resampling in normalised weight, novelty in units of k* (docs/reproducibility.md)
        self._margins: tuple[Any, float] | None = None  # (resampling margin or its thunk, novelty)
        self._margins_read: dict[str, float] = {}
        self._next_id = 0
        self._log_alpha = math.log(p.alpha)
        self._empty_var = self.kernel.k_star + p.theta_n  # empty expert: y ~ N(0, (k*+s0^2) I)
        dims = self._ll_dims = likelihood_dims(self.d_y, p.likelihood_normaliser)
        # upper bound of any expert's log N(y; mu, s^2 I): s^2 >= s0^2 (+ latent floor)
        self._gp_bound = -0.5 * dims * math.log(2.0 * math.pi * (p.theta_n + LATENT_FLOOR))

    def _new_gp(self) -> SparseOnlineGP:
        p = self.params
        return SparseOnlineGP(self._dm, self.d_y, self.kernel, p.theta_n, p.beta,
                              p.novelty_threshold, p.likelihood_normaliser,
                              prior_mean=p.gp_prior_mean == "expert")

    def _alloc_slot(self) -> int:
        if not self._free:
            old = len(self._gps)
            new = 2 * old
            self._gates.grow(new)
            self._gps.extend([None] * (new - old))
            for name in ("_ids", "_npts", "_ref"):
                arr = getattr(self, name)
                buf = np.full(new, -1 if name == "_ids" else 0, dtype=np.int64)
                buf[:old] = arr
                setattr(self, name, buf)
            self._free = list(range(new - 1, old - 1, -1))
        return self._free.pop()

    # -- Algorithm 1: learning -------------------------------------------------------------------

    def learn_one(self, x: npt.ArrayLike, y: npt.ArrayLike) -> None:
        """Learn one (perception, action) pair (paper Algorithm 1).

        Raises ``ValueError`` (model unchanged) if ``x`` or ``y`` has the wrong shape or is not
        finite.
        """
        xs = self._scaling.x_in(as_vector("x", x, self.d_x))
        ys = self._scaling.y_in(as_vector("y", y, self.d_y))
        lw, flat_part, flat_slots, offsets, terms = self._putatives(xs, ys)
        # resample to P (Fearnhead), then incorporate the point (Algorithm 1, last two lines)
        resampled: dict[str, Any] = {}
        keep, new_logw = fearnhead_resample(lw, self.params.particles, self._learn_rng,
                                            resampled, lazy=True)
        novelty = instantiate(self, keep, new_logw, flat_part, flat_slots, offsets, xs, ys,
                              terms)
        self._margins = (resampled["margin"], novelty)
        self._margins_read = {}

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

    def _putatives(self, xs: FloatArray, ys: FloatArray
                   ) -> tuple[FloatArray, IntArray, IntArray, IntArray, SlotTerms]:
        """Log weights of all putatives, touching no expert (:func:`.roger_step.putatives`)."""
        return putatives(self, xs, ys)

    # -- Algorithm 2: prediction (:mod:`.roger_predict`) ------------------------------------------

    def _map_slots(self) -> IntArray:
        return map_slots(self)

    def predict_one(self, x: npt.ArrayLike, *, rng: np.random.Generator | None = None
                    ) -> Prediction:
        """Predict the action for ``x`` (paper Algorithm 2).

        The expert of the MAP particle is chosen by gate probability: the most probable one
        (``expert_choice="argmax"``) or a draw (``"sample"``, from the model's prediction
        stream, or from ``rng`` if given).  Before any learning: the prior, ``expert_id = -1``.
        """
        pred, _ = predict(self, x, one=True, multimap=False, rng=rng)
        assert pred is not None
        return pred

    def predict_multimap(self, x: npt.ArrayLike) -> list[ExpertPrediction]:
        """Every expert of the MAP particle: gate probability (summing to 1), mean, variance."""
        _, mm = predict(self, x, one=False, multimap=True)
        assert mm is not None
        return mm

    def predict_with_multimap(self, x: npt.ArrayLike, *, rng: np.random.Generator | None = None
                              ) -> tuple[Prediction, list[ExpertPrediction]]:
        """``(predict_one(x), predict_multimap(x))`` in one pass: the gates and every expert's
        GP evaluated once (one call per control tick); the same floats and draws as the two
        calls."""
        pred, mm = predict(self, x, one=True, multimap=True, rng=rng)
        assert pred is not None and mm is not None
        return pred, mm

    def predict_table(self, x: npt.ArrayLike, *, rng: np.random.Generator | None = None
                      ) -> tuple[Prediction, MultimapTable]:
        """``predict_with_multimap(x)`` with the multimap as a table of arrays (one row per
        expert, the same floats and draws), without an object per expert: what a daemon
        builds its reply from."""
        pred, table = predict_table(self, x, rng=rng)
        assert pred is not None
        return pred, table


    # -- segmentation and introspection --------------------------------------------------------

    @property
    def n_experts(self) -> int:
        """Number of experts in the MAP particle."""
        return int(self._map_slots().size)

    @property
    def n_particles(self) -> int:
        """Particles currently carried (``P`` once there are enough putatives)."""
        return self._starts.size - 1

    def particle_slots(self, p: int) -> IntArray:
        """The expert slots of particle ``p``, in order (a copy)."""
        return self._slots[self._starts[p]: self._starts[p + 1]].copy()

    @property
    def n_unique_experts(self) -> int:
        """Distinct expert versions held by all particles together (memory in use)."""
        return int(np.count_nonzero(self._ref))

    def particle_log_weights(self) -> FloatArray:
        """Normalised log weights of the particles."""
        return self._logw.copy()

    def expert_sizes(self) -> dict[int, int]:
        """``{expert_id: points assigned}`` in the MAP particle."""
        slots = self._map_slots().tolist()
        return {int(self._ids[s]): int(self._npts[s]) for s in slots}

    def basis_sizes(self) -> dict[int, int]:
        """``{expert_id: basis vectors}`` in the MAP particle (each <= ``beta``)."""
        out = {}
        for s in self._map_slots().tolist():
            gp = self._gps[s]
            assert gp is not None
            out[int(self._ids[s])] = gp.n
        return out

    def assignments(self) -> IntArray:
        """The MAP particle's expert id for every learned point, in order.

        The settled points read as is, the last few steps traced back through the stored
        (ancestor, chosen expert) (:mod:`.history`): O(N) per call, 8 bytes per point of memory
        plus ``8 (P + 1)`` per point on which the particles' lineages still disagree.
        """
        if self.n_learned == 0:
            return np.zeros(0, dtype=np.int64)
        return self._history.assignments(int(np.argmax(self._logw)))

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
        return self._history.assignments_at(int(np.argmax(self._logw)), points)

    def distinct_experts(self) -> list[SparseOnlineGP]:
        """The distinct SOGPs held by the particles (for inspection and tests)."""
        return [g for g, r in zip(self._gps, self._ref.tolist(), strict=True)
                if r > 0 and g is not None]

    # -- state ----------------------------------------------------------------------------------

    def state_dict(self) -> dict[str, np.ndarray]:
        """Flat named arrays plus JSON metadata; see :mod:`.state`.  No object arrays."""
        return roger_state_dict(self)

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
        load_roger_state(self, state, meta)
