"""ROGER as the paper writes it: Algorithms 1 and 2 in plain numpy (Grollman & Jenkins, IROS
2010; docs/learner-math.md).

:class:`ReferenceRoger` has the constructor and the river-style API of :class:`.roger.Roger`
(``learn_one``, ``predict_one``, ``predict_multimap``, ``assignments``, ``n_experts``,
``expert_sizes``) and implements every lever of :class:`.params.RogerParams`, but keeps its
particles as plain Python objects: a particle is a log weight, a tuple of experts
(:class:`.reference_expert.ReferenceExpert`, shared between particles and never changed) and
the chain of its choices.  It is

* the page to read beside the paper: each step cites its equation or section;
* the place to try a new lever first (docs/learner-math.md §9);
* the oracle of the fast learner: on the same stream, params and seed the two make the same
  discrete decisions (it draws from the same generators as the fast learner, in the same
  order) and agree on every float to the replay tolerance (tests/learner/test_reference.py).

It imports nothing of the compiled layer.  It is slow (a few ms per step on small data) and
has no ``state_dict``.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.model_args import Seed, resolve_model_args, spawn_generators
from roger_daemon.learner.params import RogerParams
from roger_daemon.learner.prediction import ExpertPrediction, Prediction
from roger_daemon.learner.reference_expert import (
    K_STAR,
    LATENT_FLOOR,
    ReferenceExpert,
    ReferenceGate,
    ReferenceGP,
    gaussian_log_density,
)
from roger_daemon.learner.reference_resampling import fearnhead_resample
from roger_daemon.learner.scaling import AffineScaling, as_vector

__all__ = ["ReferenceRoger"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
Choices = tuple[int, Any] | None  # (expert id of the last point, the choices before it)

_STAGE1 = 4  # prune_log_margin: experts evaluated first to sharpen the bound (as the fast one)


@dataclass(frozen=True)
class Particle:
    """One partition of the points seen so far (§4): its normalised log weight, its experts
    in order of creation, and its choices, newest first."""

    log_weight: float
    experts: tuple[ReferenceExpert, ...]
    path: Choices

    def assignments(self) -> list[int]:
        """The expert id of every point, oldest first."""
        out, node = [], self.path
        while node is not None:
            out.append(node[0])
            node = node[1]
        return out[::-1]


class ReferenceRoger:
    """ROGER, Algorithms 1 and 2 in plain numpy; the same arguments as :class:`.roger.Roger`.

    ``stats`` counts the discrete events of learning (basis-vector additions, projections,
    deletions, re-inversions of ``Q``, pruned experts, resampling draws, ...).

    Examples
    --------
    >>> from roger_daemon.learner.synthetic import sqrt_multimap
    >>> data = sqrt_multimap(200)  # y = +sqrt(x) and -sqrt(x), interleaved
    >>> params = RogerParams(particles=5, theta_w=0.3, novelty_threshold=1e-3)
    >>> model = ReferenceRoger(d_x=1, d_y=1, params=params, seed=0)
    >>> for x, y in zip(data.x, data.y):
    ...     model.learn_one(x, y)
    >>> means = [float(b.mean[0]) for b in model.predict_multimap([0.5])]
    >>> min(abs(m - 0.707) for m in means) < 0.05, min(abs(m + 0.707) for m in means) < 0.05
    (True, True)
    """

    kind = "reference"

    def __init__(self, d_x: int, d_y: int, params: RogerParams | None = None,
                 seed: Seed = None) -> None:
        self.d_x, self.d_y, self.params = resolve_model_args(d_x, d_y, params)
        self._learn_rng, self._predict_rng = spawn_generators(seed)  # the fast learner's
        p = self.params
        self._scaling = AffineScaling(p, self.d_x, self.d_y)  # §8: scaling, input weights
        self._dm = self._scaling.d_model
        self._prior = ReferenceGate.prior(p, self._dm)
        self._empty_var = K_STAR + p.theta_n  # the empty expert: y ~ N(0, (k* + s0^2) I)
        self._dims = self.d_y if p.likelihood_normaliser == "multivariate" else 1
        self._particles = [Particle(0.0, (), None)]
        self._next_id = 0
        self.n_learned = 0
        self.stats: Counter[str] = Counter()

    # -- Algorithm 1 -------------------------------------------------------------------------

    def learn_one(self, x: npt.ArrayLike, y: npt.ArrayLike) -> None:
        """Learn one pair (Algorithm 1); ``ValueError`` and no change on a bad one."""
        xs = self._scaling.x_in(as_vector("x", x, self.d_x))
        ys = self._scaling.y_in(as_vector("y", y, self.d_y))
        log_w, choices = self._putatives(xs, ys)
        # resample to P (Fearnhead, §5), then put the point into each survivor's expert
        keep, new_w = fearnhead_resample(log_w, self.params.particles, self._learn_rng,
                                         self.stats)
        self._particles = self._survivors(keep, new_w, choices, xs, ys)
        self.n_learned += 1

    def _putatives(self, xs: FloatArray, ys: FloatArray
                   ) -> tuple[FloatArray, list[tuple[int, int]]]:
        """Every putative's log weight (§4), touching no expert:
        ``log w_p + log CRP(k) + log t_k(x) + log N(y; mu_k(x), s_k^2 I)``; putative ``j``
        puts the point in expert ``choices[j] = (particle, position)`` (-1: a new one)."""
        p = self.params
        experts = {id(e): e for part in self._particles for e in part.experts}
        # gate and CRP prior, once per distinct expert (pitfall 14); the CRP's common
        # denominator N + alpha (+ kappa) is dropped
        prior = {k: math.log(e.count) + e.gate.log_predictive(xs) for k, e in experts.items()}
        new_prior = math.log(p.alpha) + self._prior.log_predictive(xs)
        base, choices, owner = [], [], []
        for i, part in enumerate(self._particles):
            last = part.path[0] if part.path is not None else None
            for j, e in enumerate(part.experts):
                base.append(part.log_weight + prior[id(e)] + self._sticky(e, last))
                choices.append((i, j))
                owner.append(id(e))
            base.append(part.log_weight + new_prior + self._sticky(None, last))
            choices.append((i, -1))
            owner.append(0)
        # the GP factor: the empty expert's in closed form, each other expert's once
        new_ll = gaussian_log_density(float(ys @ ys), self._empty_var, self._dims)
        ll = self._gp_factors(experts, np.array(base), owner, new_ll, xs, ys)
        log_w = np.array([b + (new_ll if c[1] < 0 else ll[k])
                          for b, c, k in zip(base, choices, owner, strict=True)])
        return log_w, choices

    def _sticky(self, expert: ReferenceExpert | None, last: int | None) -> float:
        """§8, sticky CRP: the previous point's expert (id ``last``) weighs ``n_k + kappa``
        (``log1p(kappa / n_k)`` more); with ``kappa = inf`` every other putative (a new
        expert's, ``None``, too) weighs 0."""
        kappa = self.params.sticky_kappa
        if kappa == 0.0 or last is None:
            return 0.0
        if expert is None or expert.id != last:
            return -math.inf if math.isinf(kappa) else 0.0
        return 0.0 if math.isinf(kappa) else math.log1p(kappa / expert.count)

    def _gp_factors(self, experts: dict[int, ReferenceExpert], base: FloatArray,
                    owner: list[int], new_ll: float, xs: FloatArray, ys: FloatArray
                    ) -> dict[int, float]:
        """``log N(y; mu_k(x), (s0^2 + latent_k) I)`` of each expert (§2.4), ``-inf`` for the
        experts that ``prune_log_margin`` proves negligible: those whose best putative,
        with the GP factor's upper bound, lies more than the margin below the best putative
        known (the new experts', sharpened by the ``_STAGE1`` most promising experts first)."""
        p = self.params
        ll = dict.fromkeys(experts, -math.inf)
        todo = list(experts)
        if not math.isinf(p.prune_log_margin):
            owners = np.array(owner)
            best = {k: float(np.max(base[owners == k])) for k in experts}
            bound = -0.5 * self._dims * math.log(2.0 * math.pi * (p.theta_n + LATENT_FLOOR))
            known = float(np.max(base[owners == 0])) + new_ll
            todo = sorted((k for k in experts if best[k] + bound >= known - p.prune_log_margin),
                          key=lambda k: -best[k])
            if len(todo) > _STAGE1:
                first, todo = todo[:_STAGE1], todo[_STAGE1:]
                for k in first:
                    ll[k] = self._gp_log_likelihood(experts[k].gp, xs, ys)
                known = max(known, *(best[k] + ll[k] for k in first))
                todo = [k for k in todo if best[k] + bound >= known - p.prune_log_margin]
        for k in todo:
            ll[k] = self._gp_log_likelihood(experts[k].gp, xs, ys)
        self.stats["pruned experts"] += sum(1 for v in ll.values() if v == -math.inf)
        return ll

    def _gp_log_likelihood(self, gp: ReferenceGP, xs: FloatArray, ys: FloatArray) -> float:
        mean, latent = gp.predict(xs)
        diff = ys - mean
        return gaussian_log_density(float(diff @ diff), self.params.theta_n + latent,
                                    self._dims)

    def _survivors(self, keep: IntArray, new_w: FloatArray, choices: list[tuple[int, int]],
                   xs: FloatArray, ys: FloatArray) -> list[Particle]:
        """The resampled particles, each with the point in its chosen expert: every distinct
        chosen expert updated once (shared by the survivors that chose it, copy-on-write);
        one new expert per step, shared by every survivor that opened one."""
        updated: dict[int, ReferenceExpert] = {}
        new: ReferenceExpert | None = None
        out = []
        for j, w in zip(keep.tolist(), new_w.tolist(), strict=True):
            i, pos = choices[j]
            part = self._particles[i]
            if pos < 0:
                if new is None:
                    new = self._new_expert(xs, ys)
                chosen, experts = new, (*part.experts, new)
            else:
                old = part.experts[pos]
                if id(old) not in updated:
                    updated[id(old)] = old.with_point(xs, ys)
                chosen = updated[id(old)]
                experts = (*part.experts[:pos], chosen, *part.experts[pos + 1:])
            out.append(Particle(w, experts, (chosen.id, part.path)))
        return out

    def _new_expert(self, xs: FloatArray, ys: FloatArray) -> ReferenceExpert:
        """The empty expert after its first point (gate §3.2, GP §2.5's first point)."""
        gp = ReferenceGP(self.params, self._dm, self.d_y, self.stats)
        gp.learn(xs, ys)
        self._next_id += 1
        self.stats["new experts"] += 1
        return ReferenceExpert(self._next_id - 1, 1, self._prior.updated(xs), gp)

    # -- Algorithm 2 -------------------------------------------------------------------------

    def _map(self) -> Particle:
        """The MAP particle: the highest weight after the last resampling (§6)."""
        return self._particles[int(np.argmax([q.log_weight for q in self._particles]))]

    def _gate_probs(self, experts: tuple[ReferenceExpert, ...], xs: FloatArray) -> FloatArray:
        """``p(k | x) ∝ n_k t_k(x)`` (+ ``alpha t_0(x)`` with ``predict_empty_expert``);
        experts below ``min_support`` points get 0 unless none has it (§6, §8)."""
        p = self.params
        lg = np.array([math.log(e.count) + e.gate.log_predictive(xs) for e in experts])
        empty = (math.log(p.alpha) + self._prior.log_predictive(xs) if p.predict_empty_expert
                 else -math.inf)
        if not max(lg.max(), empty) > -math.inf:
            # every gate density underflows: p(k | x) ∝ n_k, the CRP prior alone (§6)
            lg = np.array([math.log(e.count) for e in experts])
            empty = math.log(p.alpha)
        small = np.array([e.count < p.min_support for e in experts])
        if p.min_support > 1 and not small.all():
            lg[small] = -np.inf
        if p.predict_empty_expert:
            lg = np.append(lg, empty)
        w = np.exp(lg - lg.max())
        out: FloatArray = w / w.sum()
        return out

    def _branches(self, x: npt.ArrayLike) -> tuple[FloatArray, list[ExpertPrediction]]:
        """Algorithm 2's multimap at ``x``: the gate probabilities and every expert's
        prediction (output units; the empty expert's row last when it takes part)."""
        xs = self._scaling.x_in(as_vector("x", x, self.d_x))
        sc, p = self._scaling, self.params
        experts = self._map().experts
        prior = self._prior_row()
        if not experts:
            return np.ones(1), [prior] if p.predict_empty_expert else []
        probs = self._gate_probs(experts, xs)
        rows = []
        for e, prob in zip(experts, probs.tolist(), strict=False):
            mean, latent = e.gp.predict(xs)
            rows.append(ExpertPrediction(e.id, prob, sc.mean_out(mean),
                                         sc.var_out(p.theta_n + latent), e.count))
        if p.predict_empty_expert:
            rows.append(ExpertPrediction(-1, float(probs[-1]), prior.mean, prior.var, 0))
        return probs, rows

    def predict_with_multimap(self, x: npt.ArrayLike, *, rng: np.random.Generator | None = None
                              ) -> tuple[Prediction, list[ExpertPrediction]]:
        """Algorithm 2: the MAP particle's experts at ``x``, and the one chosen by gate
        probability (argmax, or one draw with ``expert_choice="sample"`` from the prediction
        stream or ``rng``); the prior before any learning."""
        probs, rows = self._branches(x)
        if not self._map().experts:
            prior = self._prior_row()
            return Prediction(prior.mean, prior.var, -1, 1.0), rows
        if self.params.expert_choice == "argmax":
            k = int(np.argmax(probs))
        else:
            gen = self._predict_rng if rng is None else rng
            k = min(int(np.searchsorted(np.cumsum(probs), gen.random(), side="right")),
                    probs.size - 1)
        r = rows[k]
        return Prediction(r.mean, r.var, r.expert_id, r.gate_prob), rows

    def _prior_row(self) -> ExpertPrediction:
        """The empty expert's answer: mean 0, variance ``k* + s0^2`` (model units, §2.4)."""
        sc = self._scaling
        return ExpertPrediction(-1, 1.0, sc.mean_out(np.zeros(self.d_y)),
                                sc.var_out(self._empty_var), 0)

    def predict_one(self, x: npt.ArrayLike, *, rng: np.random.Generator | None = None
                    ) -> Prediction:
        """The chosen expert's prediction (Algorithm 2)."""
        return self.predict_with_multimap(x, rng=rng)[0]

    def predict_multimap(self, x: npt.ArrayLike) -> list[ExpertPrediction]:
        """Every expert of the MAP particle (draws nothing)."""
        return self._branches(x)[1]

    # -- segmentation and introspection ------------------------------------------------------

    @property
    def n_experts(self) -> int:
        """Experts of the MAP particle."""
        return len(self._map().experts)

    @property
    def n_particles(self) -> int:
        """Particles carried."""
        return len(self._particles)

    def expert_sizes(self) -> dict[int, int]:
        """``{expert_id: points}`` of the MAP particle."""
        return {e.id: e.count for e in self._map().experts}

    def basis_sizes(self) -> dict[int, int]:
        """``{expert_id: basis vectors}`` of the MAP particle."""
        return {e.id: e.gp.n for e in self._map().experts}

    def assignments(self) -> IntArray:
        """The MAP particle's expert id of every learned point, in order."""
        return np.array(self._map().assignments(), dtype=np.int64)

    def particle_log_weights(self) -> FloatArray:
        """The particles' normalised log weights, in order."""
        return np.array([q.log_weight for q in self._particles])

    def particle_assignments(self, i: int) -> IntArray:
        """Particle ``i``'s expert id of every learned point."""
        return np.array(self._particles[i].assignments(), dtype=np.int64)
