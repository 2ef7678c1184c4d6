"""What a learner returns for a query input: one prediction, or the whole multimap (as
objects, or as a table of arrays)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

__all__ = ["ExpertPrediction", "MultimapTable", "Prediction"]

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Prediction:
    """The answer of ``predict_one``: the chosen expert's predictive distribution.

    Attributes
    ----------
    mean : ndarray (d_y,)
        Predictive mean, in the caller's (unscaled) output units.
    var : ndarray (d_y,)
        Predictive variance per output (> 0), including the observation noise.
    expert_id : int
        Id of the chosen expert; ``-1`` for the prior (before any learning, or the empty
        expert when ``predict_empty_expert`` is on).
    gate_prob : float
        Gate probability of the chosen expert at this input.
    """

    mean: FloatArray
    var: FloatArray
    expert_id: int
    gate_prob: float


@dataclass(frozen=True)
class ExpertPrediction:
    """One branch of the multimap: an expert of the MAP particle and its prediction."""

    expert_id: int
    gate_prob: float
    mean: FloatArray
    var: FloatArray
    n_points: int


@dataclass(frozen=True)
class MultimapTable:
    """The multimap as arrays, one row per branch (``predict_table``): row ``j`` is what
    ``predict_multimap``'s ``j``-th :class:`ExpertPrediction` holds, the same floats. A
    daemon builds its reply from these rows without an object per expert."""

    expert_ids: list[int]
    gate_probs: list[float]
    means: FloatArray  # (branches, d_y), output units
    variances: FloatArray  # (branches, d_y), output units
    n_points: list[int]

    @classmethod
    def empty(cls, d_y: int) -> MultimapTable:
        """No branch (a model that has learned nothing, without the empty expert)."""
        return cls([], [], np.empty((0, d_y)), np.empty((0, d_y)), [])

    def prediction(self, j: int) -> Prediction:
        """Row ``j`` as ``predict_one``'s answer."""
        return Prediction(mean=self.means[j], var=self.variances[j],
                          expert_id=self.expert_ids[j], gate_prob=self.gate_probs[j])

    def experts(self) -> list[ExpertPrediction]:
        """The rows as ``predict_multimap``'s list."""
        return [ExpertPrediction(expert_id=e, gate_prob=p, mean=self.means[j],
                                 var=self.variances[j], n_points=n)
                for j, (e, p, n) in enumerate(zip(self.expert_ids, self.gate_probs,
                                                  self.n_points, strict=True))]
