"""Split gates: an expert's gate as several NIW components where its inputs form clusters.

A ROGER expert's gate is one Normal-Inverse-Wishart posterior over all of its inputs (paper
eq. 1).  When the particle filter puts two regions of perception into one expert because its
GP explains both (the pivot and the kick, or the wander and the approach: their inputs
differ, so one GP predicts both exactly), the single Gaussian spans both regions and the
expert is "impure" by the demonstrator's labels while its GP is right.  This module splits,
after training and without labels, each expert's inputs into parts whose separate NIW
posteriors explain them better than one does, by the Dirichlet-process mixture's own
posterior ratio (docs/learner-math.md §3, the NIW marginal likelihood; the CRP prior with
ROGER's ``alpha``):

    log p(X1) + log p(X2) + log alpha + log Gamma(n1) + log Gamma(n2)
        >  log p(X) + log Gamma(n)

Each part keeps its expert's GP; only the gate is split.  :class:`SplitGates` answers a
multimap whose rows are the parts (gate ``p(part | x) ∝ n_part t_part(x)``, the expert's GP
mean and variance).  The labels may afterwards name each part's group for the HCC
transitioner, as they name experts (docs/goal-scoring.md); they take no part in the split.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.cluster.vq import kmeans2
from scipy.special import gammaln, multigammaln

from roger_daemon.learner.prediction import ExpertPrediction, MultimapTable, Prediction
from roger_daemon.learner.roger_predict import drop_unsupported

__all__ = ["SPLIT_LAMBDA0", "GatePart", "SplitGates", "niw_log_marginal", "split_points"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

#: The split test's prior scatter (the NIW ``lambda0`` of the split test only; the model's
#: own gates keep theirs).  With the model's ``lambda0 = 1`` on scaled inputs the prior
#: swamps a part's scatter and nothing splits; 0.1 was chosen on demonstration streams 0–2
#: (0.01 and 8 parts scored the same there; docs/goal-scoring.md, "Split gates").
SPLIT_LAMBDA0 = 0.1


def niw_log_marginal(x: FloatArray, mu0: float, kappa0: float, lambda0: float,
                     nu0: float) -> float:
    """``log p(X)`` of the rows of ``x`` under the NIW prior (Murphy 2007 eq. 266).

    >>> round(niw_log_marginal(np.zeros((1, 1)), 0.0, 1.0, 1.0, 2.0), 4)
    -1.0397
    """
    n, d = x.shape
    kappa_n, nu_n = kappa0 + n, nu0 + n
    mean = x.mean(axis=0)
    centred = x - mean
    dev = mean - mu0
    lam_n = (np.eye(d) * lambda0 + centred.T @ centred
             + (kappa0 * n / kappa_n) * np.outer(dev, dev))
    sign, logdet_n = np.linalg.slogdet(lam_n)
    if sign <= 0:
        raise ValueError("niw_log_marginal: the posterior scale is not positive definite")
    return float(-0.5 * n * d * math.log(math.pi)
                 + multigammaln(0.5 * nu_n, d) - multigammaln(0.5 * nu0, d)
                 + 0.5 * nu0 * d * math.log(lambda0) - 0.5 * nu_n * logdet_n
                 + 0.5 * d * (math.log(kappa0) - math.log(kappa_n)))


def _gain(x: FloatArray, parts: IntArray, prior: tuple[float, float, float, float],
          log_alpha: float) -> float:
    """The log posterior ratio of ``x`` split by ``parts`` (0/1) against ``x`` whole."""
    a, b = x[parts == 0], x[parts == 1]
    whole = niw_log_marginal(x, *prior) + float(gammaln(len(x)))
    split = (niw_log_marginal(a, *prior) + niw_log_marginal(b, *prior) + log_alpha
             + float(gammaln(len(a)) + gammaln(len(b))))
    return split - whole


def _candidates(x: FloatArray, rng: np.random.Generator) -> list[IntArray]:
    """Two-way splits to score: 2-means, and along each input dimension its widest gap."""
    _, two = kmeans2(x, 2, minit="++", seed=rng, iter=20)
    out = [np.asarray(two, dtype=np.int64)]
    for j in range(x.shape[1]):
        v = np.sort(x[:, j])
        gaps = np.diff(v)
        if gaps.size and gaps.max() > 0.0:
            cut = v[int(gaps.argmax())]
            out.append((x[:, j] > cut).astype(np.int64))
    return out


def split_points(x: FloatArray, prior: tuple[float, float, float, float], log_alpha: float,
                 *, max_parts: int, min_points: int, seed: int) -> IntArray:
    """Part index of every row of ``x``: recursive two-way splits (the best of
    :func:`_candidates`) kept while the posterior ratio favours them (module docstring), at
    most ``max_parts`` parts of at least ``min_points`` rows each.  Deterministic for a
    ``seed``."""
    parts = np.zeros(len(x), dtype=np.int64)
    queue = [0]
    n_parts = 1
    rng = np.random.default_rng(seed)
    while queue and n_parts < max_parts:
        p = queue.pop(0)
        idx = np.flatnonzero(parts == p)
        if len(idx) < 2 * min_points:
            continue
        scored = [(_gain(x[idx], c, prior, log_alpha), i, c)
                  for i, c in enumerate(_candidates(x[idx], rng))
                  if np.bincount(c, minlength=2).min() >= min_points]
        if not scored:
            continue
        gain, _, two = max(scored, key=lambda t: (t[0], -t[1]))
        if gain <= 0.0:
            continue
        parts[idx[two == 1]] = n_parts
        queue += [p, n_parts]
        n_parts += 1
    return parts


@dataclass(frozen=True)
class GatePart:
    """One part of a split gate: its expert, its points' count and its own NIW slot."""

    part: int
    expert: int
    n: int


class SplitGates:
    """A trained ROGER model's experts with split gates (module docstring).

    ``x`` is the stream the model learned, in order (``model.assignments()`` gives each point's
    expert).  Only the MAP particle's experts are split.  It answers as a model does
    (:meth:`predict_table`, :meth:`predict_multimap`, :meth:`predict_one`,
    :meth:`assignments`), with the parts in place of the experts: the HCC transitioner, the
    learned FSM (``roger_daemon.fsm.fit_fsm``) and the evaluation take it as they take ROGER.
    ``lambda0`` is the prior scatter of the split test only (:data:`SPLIT_LAMBDA0`).
    """

    def __init__(self, model: object, x: npt.ArrayLike, *, max_parts: int = 4,
                 min_points: int | None = None, seed: int = 0,
                 lambda0: float = SPLIT_LAMBDA0) -> None:
        terms = model.terms  # type: ignore[attr-defined]
        self.model = model
        self.terms = terms
        scaling = terms.scaling
        xs = np.array([scaling.x_in(np.asarray(r, dtype=np.float64))
                       for r in np.asarray(x, dtype=np.float64)])
        assignments = np.asarray(model.assignments(), dtype=np.int64)  # type: ignore[attr-defined]
        p = terms.params
        self._support = p.min_support
        # a part must be able to compete: at least the model's min_support points
        least = max(10, p.min_support) if min_points is None else min_points
        prior = (p.mu0, p.kappa0, lambda0, p.nu0_for(terms.d_x))
        self.gates = terms.new_gates()
        self.parts: list[GatePart] = []
        self.point_part = np.zeros(len(assignments), dtype=np.int64)
        for expert in np.unique(assignments):
            idx = np.flatnonzero(assignments == expert)
            split = split_points(xs[idx], prior, terms.log_alpha, max_parts=max_parts,
                                 min_points=least, seed=seed + int(expert))
            for j in range(int(split.max()) + 1):
                rows = idx[split == j]
                slot = len(self.parts)
                self.gates.grow(slot + 1)
                self.gates.set_prior(slot)
                for r in rows:
                    self.gates.update(slot, xs[r])
                self.point_part[rows] = slot
                self.parts.append(GatePart(part=slot, expert=int(expert), n=len(rows)))
        self._slots = np.arange(len(self.parts), dtype=np.int64)
        self._counts = np.array([q.n for q in self.parts], dtype=np.int64)

    def part_probs(self, x: npt.ArrayLike) -> FloatArray:
        """``p(part | x) ∝ n_part t_part(x)`` over every part, the parts below the model's
        ``min_support`` out of the competition as its experts are (docs/learner-math.md §6)."""
        xs = self.terms.scaling.x_in(np.asarray(x, dtype=np.float64))
        lg = np.empty(len(self.parts))
        self.gates.crp_log_terms(self._slots, xs, self._counts, lg)
        if not lg.max() > -np.inf:
            lg = np.log(self._counts.astype(np.float64))
        drop_unsupported(lg, self._counts, self._support)
        w = np.exp(lg - lg.max())
        out: FloatArray = w / w.sum()
        return out

    def assignments(self) -> IntArray:
        """The part of every learned point, in order (as ``Roger.assignments`` gives experts)."""
        return self.point_part.copy()

    def predict_table(self, x: npt.ArrayLike, *, rng: np.random.Generator | None = None
                      ) -> tuple[Prediction, MultimapTable]:
        """The model's multimap with one row per part: the part's gate probability, its
        expert's GP mean and variance; ``predict_one``'s answer is the likeliest part's row."""
        _, table = self.model.predict_table(x, rng=rng)  # type: ignore[attr-defined]
        row = {e: j for j, e in enumerate(table.expert_ids)}
        probs = self.part_probs(x)
        keep = [q for q in self.parts if q.expert in row]
        rows = [row[q.expert] for q in keep]
        out = MultimapTable([q.part for q in keep], [float(probs[q.part]) for q in keep],
                            table.means[rows], table.variances[rows], [q.n for q in keep])
        return out.prediction(int(np.argmax(out.gate_probs))), out

    def predict_multimap(self, x: npt.ArrayLike) -> list[ExpertPrediction]:
        """:meth:`predict_table`'s rows as a list."""
        return self.predict_table(x)[1].experts()

    def predict_one(self, x: npt.ArrayLike) -> Prediction:
        """The likeliest part's row."""
        return self.predict_table(x)[0]
