"""The learner contract every model honours (``docs/learner-api.md``), as code.

``Roger`` and ``UnimapGP`` satisfy :class:`Learner`; ``tests/learner/test_conformance.py`` runs
one conformance suite over every model in :data:`MODELS` (in the spirit of river's
``check_estimator``): a new model is added there and must pass it unchanged.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.prediction import ExpertPrediction, Prediction
from roger_daemon.learner.roger import Roger
from roger_daemon.learner.unimap import UnimapGP

__all__ = ["MODELS", "Learner"]


@runtime_checkable
class Learner(Protocol):
    """Incremental multimap regression: ``learn_one`` / ``predict_one`` / ``predict_multimap``.

    * ``learn_one(x, y)``: one (perception, action) pair; a bad shape or a non-finite value
      raises ``ValueError`` and leaves the model unchanged.
    * ``predict_one(x)``: the chosen expert's mean and variance (the prior before learning,
      ``expert_id == -1``); with the default ``expert_choice="argmax"`` it changes nothing.
    * ``predict_multimap(x)``: every expert of the MAP particle, gate probabilities summing
      to at most 1 (the rest is the empty expert's share).
    * ``predict_with_multimap(x)``: both answers from one pass (one call per control tick),
      equal to ``predict_one(x)`` then ``predict_multimap(x)``.
    * ``state_dict()`` / ``from_state_dict()``: named arrays without object dtype; the restored
      model continues exactly as the original would.
    """

    kind: str
    d_x: int
    d_y: int

    @property
    def n_learned(self) -> int: ...

    @property
    def n_experts(self) -> int: ...

    def learn_one(self, x: npt.ArrayLike, y: npt.ArrayLike) -> None: ...

    def predict_one(self, x: npt.ArrayLike) -> Prediction: ...

    def predict_multimap(self, x: npt.ArrayLike) -> list[ExpertPrediction]: ...

    def predict_with_multimap(self, x: npt.ArrayLike
                              ) -> tuple[Prediction, list[ExpertPrediction]]: ...

    def assignments(self) -> npt.NDArray[np.int64]: ...

    def expert_sizes(self) -> dict[int, int]: ...

    def state_dict(self) -> dict[str, np.ndarray]: ...

    @classmethod
    def from_state_dict(cls, state: Mapping[str, np.ndarray]) -> Any: ...


#: Every learner the project ships; the conformance suite runs over each.
MODELS: tuple[type[Roger] | type[UnimapGP], ...] = (Roger, UnimapGP)
