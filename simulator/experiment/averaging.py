"""Does a controller fail by averaging the multimap? (the paper's DPA, section IV.B)

The unimap GP learns one function from all the demonstrations; where the demonstrator did
different things at the same perception (seek turns, aim turns the other way, kick stands) its
mean is a blend that is none of them. This module measures that, tick by tick, on an episode's
perceptions and commands against the demonstration stream the model learned:

* the tick's *neighbourhood* is the ``k`` demonstrated perceptions nearest to the robot's
  (Chebyshev distance, the metric of :mod:`simulator.aliasing`);
* the tick is *aliased* when two of those demonstrated actions conflict
  (:func:`simulator.aliasing.conflicting`: an entry differs by more than half its scale, or the
  action indicators decode differently);
* the command *averages* when the tick is aliased and the command conflicts with every one of
  the neighbours' actions: at a perception where the demonstrator did several things, the
  controller does none of them.

An episode's ``averaged_share`` is its averaging ticks over all its ticks.  Standing still can
be either this (left and right turns, or a turn and a standing kick, blended into "no turn") or
the absorbing prior of a GP far from its data (docs/goal-scoring.md); the share tells which.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from simulator.aliasing import conflict_within, conflicting

__all__ = ["AVERAGED_EPISODE_SHARE", "MultimapNeighbourhood"]

FloatArray = npt.NDArray[np.float64]

#: An episode "fails by averaging" when at least this share of its ticks average the multimap.
AVERAGED_EPISODE_SHARE = 0.25


class MultimapNeighbourhood:
    """The demonstrations a model learned, queried for the averaging test (module docstring)."""

    def __init__(self, x: FloatArray, y: FloatArray, k: int = 10, conflict: float = 0.5) -> None:
        self.x = np.asarray(x, dtype=np.float64)
        self.y = np.asarray(y, dtype=np.float64)
        if self.x.ndim != 2 or self.y.ndim != 2 or len(self.x) != len(self.y) or not len(self.x):
            raise ValueError(f"need matching non-empty 2-D x and y; got {self.x.shape} and "
                             f"{self.y.shape}")
        self.k = min(int(k), len(self.x))
        self.conflict = float(conflict)
        self._tree = cKDTree(self.x)

    def averaged_ticks(self, xs: FloatArray, commands: FloatArray
                       ) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.bool_]]:
        """Per tick: (aliased, averaged) for perceptions ``xs`` and the commands sent there."""
        xs = np.atleast_2d(np.asarray(xs, dtype=np.float64))
        cmds = np.atleast_2d(np.asarray(commands, dtype=np.float64))
        if len(xs) != len(cmds):
            raise ValueError(f"{len(xs)} perceptions but {len(cmds)} commands")
        if not len(xs):
            return np.zeros(0, dtype=bool), np.zeros(0, dtype=bool)
        _, idx = self._tree.query(xs, k=self.k, p=np.inf)
        idx = np.asarray(idx).reshape(len(xs), self.k)
        near = self.y[idx]  # (ticks, k, 9)
        aliased = conflict_within(near, self.conflict)
        repeated = np.repeat(cmds, self.k, axis=0)
        off = conflicting(repeated, near.reshape(-1, near.shape[2]), self.conflict)
        averaged = aliased & off.reshape(len(xs), self.k).all(axis=1)
        return aliased, averaged

    def episode_summary(self, xs: FloatArray, commands: FloatArray) -> dict[str, Any]:
        """``aliased_share`` and ``averaged_share`` of one episode's ticks."""
        aliased, averaged = self.averaged_ticks(xs, commands)
        n = max(len(aliased), 1)
        return {"aliased_share": round(float(aliased.sum()) / n, 3),
                "averaged_share": round(float(averaged.sum()) / n, 3)}
