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
that contain them (a particle is an int array of slots); a slot is copied only when a survivor
updates an expert that another survivor keeps unchanged (copy-on-write), and survivors that
choose the same slot share one updated copy.  Per step each *unique* expert is evaluated once
(all gates in one batched product, then each GP once, whatever the number of particles that
share it), and the chosen experts are updated together (:func:`.sogp.update_many`), so the
cost is bounded by (unique experts) x ``beta^2``, never by the data seen.  An opt-in bound
(``prune_log_margin``) skips the GP of experts whose putatives cannot carry weight.  The
segmentation history costs O(P) per step: survivors' ancestor index and chosen expert id,
traced back by :meth:`Roger.assignments`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.gate import GatePool
from roger_daemon.learner.kernel import RBFKernel
from roger_daemon.learner.params import RogerParams
from roger_daemon.learner.prediction import ExpertPrediction, Prediction
from roger_daemon.learner.resampling import fearnhead_resample
from roger_daemon.learner.roger_state import load_roger_state, roger_state_dict
from roger_daemon.learner.scaling import AffineScaling, as_vector
from roger_daemon.learner.sogp import (
    LATENT_FLOOR,
    SparseOnlineGP,
    gaussian_log_likelihood,
    update_many,
)
from roger_daemon.learner.state import (
    Seed,
    spawn_generators,
    unpack_meta,
)

__all__ = ["Roger"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
Terms = tuple[FloatArray, FloatArray, FloatArray, float]

_NEW = np.array([-1], dtype=np.int64)  # the "+1" empty expert in a putative list
_STAGE1 = 4  # experts evaluated first to sharpen the pruning bound


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
        self._particles: list[IntArray] = [np.zeros(0, dtype=np.int64)]
        self._logw = np.zeros(1)
        self._hist_anc = np.zeros((0, p.particles), dtype=np.int32)
        self._hist_eid = np.zeros((0, p.particles), dtype=np.int64)
        self.n_learned = 0
        # how close the last learn_one's discrete decisions were to flipping (diagnostic, not
        # state): resampling in normalised weight, novelty in units of k* (docs/reproducibility.md)
        self.last_margins: dict[str, float] = {}
        self._next_id = 0
        self._log_alpha = math.log(p.alpha)
        self._empty_var = self.kernel.k_star + p.theta_n  # empty expert: y ~ N(0, (k*+s0^2) I)
        dims = self.d_y if p.likelihood_normaliser == "multivariate" else 1
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
        resampled: dict[str, float] = {}
        keep, new_logw = fearnhead_resample(lw, self.params.particles, self._learn_rng,
                                            resampled)
        novelty = self._instantiate(keep, new_logw, flat_part, flat_slots, offsets, xs, ys,
                                    terms)
        self.last_margins = {"resampling": resampled["margin"], "novelty": novelty}

    def _putatives(self, xs: FloatArray, ys: FloatArray
                   ) -> tuple[FloatArray, IntArray, IntArray, IntArray, dict[int, Terms]]:
        """Log weights of all putatives (Algorithm 1, inner loops), touching no expert.

        Putative ``j`` assigns the point to expert slot ``flat_slots[j]`` (``-1``: a new one)
        of particle ``flat_part[j]``; particle ``p``'s putatives start at ``offsets[p]``.
        """
        p = self.params
        parts = self._particles
        sizes = np.fromiter((a.size + 1 for a in parts), dtype=np.int64, count=len(parts))
        flat_slots = np.concatenate([a for s in parts for a in (s, _NEW)])
        flat_part = np.repeat(np.arange(len(parts)), sizes)
        offsets = np.cumsum(sizes) - sizes
        is_new = flat_slots < 0
        old_slots = flat_slots[~is_new]
        cap = len(self._gps)

        # gates of all unique experts, batched (§3.4); CRP prior n_k (N + alpha dropped, §4)
        live = np.flatnonzero(self._ref > 0)
        slot_gate = np.zeros(cap)
        slot_gate[live] = self._gates.log_predictive(live, xs)
        slot_gate[live] += np.log(self._npts[live])
        base = self._logw[flat_part]
        base[is_new] += self._log_alpha + self._gates.prior_log_predictive(xs)
        base[~is_new] += slot_gate[old_slots]
        if p.sticky_kappa > 0.0 and self.n_learned > 0:
            self._add_stickiness(base, flat_part, flat_slots, is_new)

        # GP factor: the empty expert analytically, the others once per unique expert
        ll_new = float(gaussian_log_likelihood(float(ys @ ys), self._empty_var, self.d_y,
                                               p.likelihood_normaliser))
        slot_ll, terms = self._gp_factors(xs, ys, live, base, is_new, old_slots, ll_new, cap)
        lw = base + np.where(is_new, ll_new, slot_ll[flat_slots])
        return lw, flat_part, flat_slots, offsets, terms

    def _add_stickiness(self, base: FloatArray, flat_part: IntArray, flat_slots: IntArray,
                        is_new: npt.NDArray[np.bool_]) -> None:
        """Sticky CRP (Fox et al. 2008; paper section V): the expert of the previous point in
        each particle weighs ``n_k + kappa`` instead of ``n_k``; with ``kappa = inf`` every
        other putative of that particle gets weight 0.  The common normaliser
        ``N + alpha + kappa`` is dropped like ``N + alpha`` (docs/learner-math.md)."""
        kappa = self.params.sticky_kappa
        prev_ids = self._hist_eid[self.n_learned - 1]  # chosen expert id of each particle
        ids = np.where(is_new, -2, self._ids[np.where(is_new, 0, flat_slots)])
        is_prev = ids == prev_ids[flat_part]
        if math.isinf(kappa):
            base[~is_prev] = -np.inf
        else:
            base[is_prev] += np.log1p(kappa / self._npts[flat_slots[is_prev]])

    def _gp_factors(self, xs: FloatArray, ys: FloatArray, live: IntArray, base: FloatArray,
                    is_new: npt.NDArray[np.bool_], old_slots: IntArray, ll_new: float, cap: int
                    ) -> tuple[FloatArray, dict[int, Terms]]:
        """``log N(y; mu_s(x), s_s^2 I)`` per slot, ``-inf`` where provably negligible."""
        slot_ll = np.full(cap, -np.inf)
        terms: dict[int, Terms] = {}
        if live.size == 0:
            return slot_ll, terms
        margin = self.params.prune_log_margin
        if math.isinf(margin):
            cand = live
            order: IntArray = cand
        else:
            # best (particle weight + CRP + gate) over the putatives of each slot
            best = np.full(cap, -np.inf)
            np.maximum.at(best, old_slots, base[~is_new])
            known = float(np.max(base[is_new])) + ll_new  # exact, from the empty expert
            upper = best[live] + self._gp_bound
            cand = live[upper >= known - margin]
            order = cand[np.argsort(-best[cand], kind="stable")]
        gps = self._gps

        p = self.params

        def evaluate(slots: IntArray) -> None:
            if slots.size == 0:
                return
            batch = []
            for s in slots.tolist():
                gp = gps[s]
                assert gp is not None
                t = gp.terms(xs)
                terms[s] = t
                batch.append(t)
            diff = ys - np.stack([t[2] for t in batch])
            var = p.theta_n + np.array([t[3] for t in batch])
            slot_ll[slots] = gaussian_log_likelihood(np.einsum("ij,ij->i", diff, diff), var,
                                                     self.d_y, p.likelihood_normaliser)

        if math.isinf(margin) or order.size <= _STAGE1:
            evaluate(order)
            return slot_ll, terms
        first, rest = order[:_STAGE1], order[_STAGE1:]
        evaluate(first)
        known = max(known, float(np.max(best[first] + slot_ll[first])))
        evaluate(rest[best[rest] + self._gp_bound >= known - margin])
        return slot_ll, terms

    def _instantiate(self, keep: IntArray, new_logw: FloatArray, flat_part: IntArray,
                     flat_slots: IntArray, offsets: IntArray, xs: FloatArray, ys: FloatArray,
                     terms: dict[int, Terms]) -> float:
        """Build the surviving particles; update each chosen expert once (copy-on-write).

        Returns the smallest novelty-test margin of the updated experts (``inf``: none).
        """
        parts = self._particles
        surv_parent = flat_part[keep]
        surv_slot = flat_slots[keep]
        surv_pos = keep - offsets[surv_parent]
        cap = len(self._gps)
        # how many survivors contain each slot, and how many of them chose it
        contains = np.bincount(np.concatenate([parts[i] for i in surv_parent.tolist()]),
                               minlength=cap)
        chose = np.bincount(surv_slot[surv_slot >= 0], minlength=cap)
        target: dict[int, int] = {}
        upd_gps: list[SparseOnlineGP] = []
        upd_terms: list[Terms | None] = []
        upd_slots: list[int] = []
        for s in np.unique(surv_slot).tolist():
            if s < 0:  # a new expert, shared by every survivor that opened one this step
                t = self._alloc_slot()
                gp = self._new_gp()
                gp.update(xs, ys)
                self._gps[t] = gp
                self._gates.set_prior_updated(t, xs)
                self._ids[t] = self._next_id
                self._next_id += 1
                self._npts[t] = 1
            else:
                src = self._gps[s]
                assert src is not None
                if contains[s] == chose[s]:  # nobody keeps the old version: update in place
                    t, gp = s, src
                else:
                    t = self._alloc_slot()
                    gp = src.copy()
                    self._gps[t] = gp
                    self._gates.copy_slot(t, s)
                    self._ids[t] = self._ids[s]
                upd_gps.append(gp)
                upd_terms.append(terms.get(s))
                upd_slots.append(t)
                self._npts[t] = self._npts[s] + 1
            target[s] = t
        # incorporate the point: SOGP (§2.5, batched hot path) and NIW gate (§3.2)
        update_many(upd_gps, xs, ys, upd_terms)
        if upd_slots:
            self._gates.update_many(np.array(upd_slots, dtype=np.int64), xs)
        new_parts: list[IntArray] = []
        chosen_ids = np.empty(keep.size, dtype=np.int64)
        for j, (i, s, pos) in enumerate(zip(surv_parent.tolist(), surv_slot.tolist(),
                                            surv_pos.tolist(), strict=True)):
            t = target[s]
            arr = parts[i]
            if s < 0:
                arr = np.append(arr, t)
            elif t != s:
                arr = arr.copy()
                arr[pos] = t
            new_parts.append(arr)  # particle arrays are never mutated: sharing is safe
            chosen_ids[j] = self._ids[t]
        # reference counts; free the slots no survivor holds
        cap = len(self._gps)
        new_ref = np.bincount(np.concatenate(new_parts), minlength=cap)
        for s in np.flatnonzero((self._ref > 0) & (new_ref == 0)).tolist():
            self._gps[s] = None
            self._ids[s] = -1
            self._npts[s] = 0
            self._free.append(s)
        self._free.sort(reverse=True)
        self._ref = new_ref
        self._particles = new_parts
        self._logw = new_logw
        self._record(surv_parent, chosen_ids)
        self.n_learned += 1
        return min((gp.novelty_margin for gp in upd_gps), default=math.inf)

    def _record(self, ancestors: IntArray, expert_ids: IntArray) -> None:
        """Append one row of segmentation history (O(P) per step)."""
        t = self.n_learned
        if t >= self._hist_anc.shape[0]:
            grow = max(64, self._hist_anc.shape[0])
            width = self.params.particles
            self._hist_anc = np.concatenate(
                [self._hist_anc, np.full((grow, width), -1, dtype=np.int32)])
            self._hist_eid = np.concatenate(
                [self._hist_eid, np.full((grow, width), -1, dtype=np.int64)])
        n = ancestors.size
        self._hist_anc[t, :n] = ancestors
        self._hist_anc[t, n:] = -1
        self._hist_eid[t, :n] = expert_ids
        self._hist_eid[t, n:] = -1

    # -- Algorithm 2: prediction -----------------------------------------------------------------

    def _map_slots(self) -> IntArray:
        """Slots of the MAP particle (highest weight after the last resampling, §6)."""
        return self._particles[int(np.argmax(self._logw))]

    def _gate_probs(self, slots: IntArray, xs: FloatArray) -> FloatArray:
        """``p(k | x) ∝ n_k t_k(x)`` over ``slots`` (+ ``alpha t_0(x)`` if the empty expert
        takes part), normalised (paper Algorithm 2, docs/learner-math.md §6)."""
        lg = self._gates.log_predictive(slots, xs) + np.log(self._npts[slots])
        support = self.params.min_support
        if support > 1:  # too small to compete, unless no expert has the support
            small = self._npts[slots] < support
            if not small.all():
                lg[small] = -np.inf
        if self.params.predict_empty_expert:
            lg = np.append(lg, self._log_alpha + self._gates.prior_log_predictive(xs))
        w = np.exp(lg - np.max(lg))
        out: FloatArray = w / np.sum(w)
        return out

    def _prior_prediction(self, gate_prob: float) -> Prediction:
        s = self._scaling
        return Prediction(mean=s.mean_out(np.zeros(self.d_y)), var=s.var_out(self._empty_var),
                          expert_id=-1, gate_prob=gate_prob)

    def predict_one(self, x: npt.ArrayLike, *, rng: np.random.Generator | None = None
                    ) -> Prediction:
        """Predict the action for ``x`` (paper Algorithm 2).

        The expert of the MAP particle is chosen by gate probability: the most probable one
        (``expert_choice="argmax"``) or a draw (``"sample"``, from the model's prediction
        stream, or from ``rng`` if given).  Before any learning: the prior, ``expert_id = -1``.
        """
        xs = self._scaling.x_in(as_vector("x", x, self.d_x))
        slots = self._map_slots()
        if slots.size == 0:
            return self._prior_prediction(1.0)
        probs = self._gate_probs(slots, xs)
        if self.params.expert_choice == "argmax":
            k = int(np.argmax(probs))
        else:
            gen = self._predict_rng if rng is None else rng
            k = min(int(np.searchsorted(np.cumsum(probs), gen.random(), side="right")),
                    probs.size - 1)
        if k == slots.size:  # the empty expert
            return self._prior_prediction(float(probs[k]))
        s = int(slots[k])
        gp = self._gps[s]
        assert gp is not None
        mean, var = gp.predict(xs)
        return Prediction(mean=self._scaling.mean_out(mean), var=self._scaling.var_out(var),
                          expert_id=int(self._ids[s]), gate_prob=float(probs[k]))

    def predict_multimap(self, x: npt.ArrayLike) -> list[ExpertPrediction]:
        """Every expert of the MAP particle: gate probability (summing to 1), mean, variance."""
        xs = self._scaling.x_in(as_vector("x", x, self.d_x))
        slots = self._map_slots()
        sc = self._scaling
        out: list[ExpertPrediction] = []
        if slots.size == 0 and not self.params.predict_empty_expert:
            return out
        probs = self._gate_probs(slots, xs) if slots.size else np.ones(1)
        for k, s in enumerate(slots.tolist()):
            gp = self._gps[s]
            assert gp is not None
            mean, var = gp.predict(xs)
            out.append(ExpertPrediction(expert_id=int(self._ids[s]), gate_prob=float(probs[k]),
                                        mean=sc.mean_out(mean), var=sc.var_out(var),
                                        n_points=int(self._npts[s])))
        if self.params.predict_empty_expert:
            prior = self._prior_prediction(float(probs[-1]))
            out.append(ExpertPrediction(expert_id=-1, gate_prob=prior.gate_prob, mean=prior.mean,
                                        var=prior.var, n_points=0))
        return out

    # -- segmentation and introspection --------------------------------------------------------

    @property
    def n_experts(self) -> int:
        """Number of experts in the MAP particle."""
        return int(self._map_slots().size)

    @property
    def n_particles(self) -> int:
        """Particles currently carried (``P`` once there are enough putatives)."""
        return len(self._particles)

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

        Traced back through the stored (ancestor, chosen expert) of each step: O(N) per call,
        O(P) memory per step.
        """
        n = self.n_learned
        anc = self._hist_anc[:n].tolist()  # plain lists: the pointer chase stays in Python
        eid = self._hist_eid[:n].tolist()
        out = [0] * n
        j = int(np.argmax(self._logw))
        for t in range(n - 1, -1, -1):
            out[t] = eid[t][j]
            j = anc[t][j]
        return np.array(out, dtype=np.int64)

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
