"""What a learner returns for a query input: one prediction, or the whole multimap."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

__all__ = ["ExpertPrediction", "Prediction"]

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
