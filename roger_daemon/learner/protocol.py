"""The learner contract every model honours (``docs/learner-api.md``), as code.

``Roger`` and ``UnimapGP`` satisfy :class:`Learner`; ``tests/learner/test_conformance.py`` runs
one conformance suite over every model of :data:`MODELS` (in the spirit of river's
``check_estimator``): a new model is added to the registry
(:data:`roger_daemon.learner.registry.MODELS`) and must pass it unchanged.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.prediction import ExpertPrediction, MultimapTable, Prediction
from roger_daemon.learner.registry import MODELS as _REGISTRY
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
      equal to ``predict_one(x)`` then ``predict_multimap(x)``; ``predict_table(x)`` the same
      with the multimap as arrays, one row per expert (a daemon's reply is built from it).
    * ``state_dict()`` / ``from_state_dict()``: named arrays without object dtype; the restored
      model continues exactly as the original would.
    """

    kind: str
    d_x: int
    d_y: int

    @property
    def n_learned(self) -> int:
        """Pairs learned so far."""
        ...

    @property
    def n_experts(self) -> int:
        """Experts of the MAP particle (1 for the unimap baseline once it has learned)."""
        ...

    def learn_one(self, x: npt.ArrayLike, y: npt.ArrayLike) -> None:
        """Learn one pair; ``ValueError`` and no change on a bad shape or value."""
        ...

    def predict_one(self, x: npt.ArrayLike) -> Prediction:
        """The chosen expert's prediction for ``x``."""
        ...

    def predict_multimap(self, x: npt.ArrayLike) -> list[ExpertPrediction]:
        """Every expert of the MAP particle at ``x``."""
        ...

    def predict_with_multimap(self, x: npt.ArrayLike
                              ) -> tuple[Prediction, list[ExpertPrediction]]:
        """``(predict_one(x), predict_multimap(x))`` from one pass."""
        ...

    def predict_table(self, x: npt.ArrayLike) -> tuple[Prediction, MultimapTable]:
        """``predict_with_multimap(x)`` with the multimap as a :class:`.MultimapTable`."""
        ...

    def assignments(self) -> npt.NDArray[np.int64]:
        """The MAP particle's expert id of every learned point, in order."""
        ...

    def unsettled_points(self) -> npt.NDArray[np.int64]:
        """The points whose expert further learning may still change (ascending); every other
        point's expert is final (incremental labelling)."""
        ...

    def assignments_at(self, points: npt.ArrayLike) -> npt.NDArray[np.int64]:
        """``assignments()[points]`` without building the whole array."""
        ...

    def expert_sizes(self) -> dict[int, int]:
        """``{expert_id: points}`` of the MAP particle."""
        ...

    def state_dict(self) -> dict[str, np.ndarray]:
        """Named arrays (no object dtype) from which the model continues exactly."""
        ...

    @classmethod
    def from_state_dict(cls, state: Mapping[str, np.ndarray]) -> Any:
        """The model :meth:`state_dict` describes."""
        ...


#: Every learner the project ships (the registry's); the conformance suite runs over each.
MODELS: tuple[type[Roger] | type[UnimapGP], ...] = tuple(_REGISTRY.values())
