"""ROGER's segmentation history: which expert each particle gave every learned point.

Each step appends one row: for each survivor, the index of its ancestor among the previous
step's particles and the id of the expert it put the point in (paper Algorithm 1).  Tracing a
final particle back through the ancestors gives its assignment of every point
(:meth:`SegmentationHistory.assignments`).

Going back in time the lineages of the ``P`` particles meet (resampling keeps copies of the
heavy particles, so after some tens of steps they all descend from one): before that row every
present particle, and every particle that will ever descend from them, assigns the points the
same way.  That prefix is *settled*: it is kept as one expert id per point (8 bytes) instead of
``P`` ancestors and ids (12 ``P`` bytes, 120 bytes at ``P = 10``), and only the rows since the
lineages last met are kept per particle (docs/learner-math.md §4).  This is exact: the
assignments are the same as with the full table.  The split is canonical (the latest row at
which the lineages meet, whatever was settled before), so a state dict does not depend on when
the model was saved or restored.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from roger_daemon.learner import jit

__all__ = ["SegmentationHistory"]

IntArray = npt.NDArray[np.int64]
AncArray = npt.NDArray[np.int32]

_MIN_ROWS = 64


class SegmentationHistory:
    """Per-step (ancestor, chosen expert id) of each survivor, settled prefix collapsed."""

    def __init__(self, width: int) -> None:
        self.width = int(width)
        self._settled = np.zeros(_MIN_ROWS, dtype=np.int64)
        self.n_settled = 0
        self._anc = np.full((_MIN_ROWS, self.width), -1, dtype=np.int32)
        self._eid = np.full((_MIN_ROWS, self.width), -1, dtype=np.int64)
        self.n_rows = 0  # rows kept per particle (since the lineages last met)
        self._tried = 0  # len(self) when settle() last ran

    def __len__(self) -> int:
        return self.n_settled + self.n_rows

    # -- learning ------------------------------------------------------------------------------

    def append(self, ancestors: npt.ArrayLike, expert_ids: npt.ArrayLike) -> None:
        """Record one step: survivor ``j`` descends from particle ``ancestors[j]`` of the previous
        step and put the point in expert ``expert_ids[j]``.  Amortised O(P)."""
        if self.n_rows == self._anc.shape[0]:
            self.settle()
            if 2 * self.n_rows > self._anc.shape[0]:  # the lineages meet far back: widen
                self._anc = _grown(self._anc, 2 * self._anc.shape[0], -1)
                self._eid = _grown(self._eid, 2 * self._eid.shape[0], -1)
        anc = np.asarray(ancestors)
        n = anc.size
        t = self.n_rows
        self._anc[t, :n] = anc
        self._anc[t, n:] = -1
        self._eid[t, :n] = expert_ids
        self._eid[t, n:] = -1
        self.n_rows += 1

    def last_ids(self) -> IntArray:
        """The expert id each present particle chose at the last step (``-1`` past the end)."""
        if self.n_rows == 0:
            raise IndexError("no step recorded")
        last: IntArray = self._eid[self.n_rows - 1]
        return last

    def settle(self) -> None:
        """Collapse the rows before the latest one at which all present lineages meet.

        Does not change :meth:`assignments`; leaves at least the last row per particle.
        """
        self._tried = len(self)
        if self.n_rows == 0:
            return
        alive = int(np.count_nonzero(self._eid[self.n_rows - 1] >= 0))
        row, particle = jit.coalescence_row(self._anc, self.n_rows, alive)
        if row <= 0:
            return
        prefix = jit.trace_assignments(self._anc, self._eid, row,
                                       int(self._anc[row, particle]))
        need = self.n_settled + row
        if need > self._settled.size:
            self._settled = _grown(self._settled, max(need, 2 * self._settled.size), 0)
        self._settled[self.n_settled:need] = prefix
        self.n_settled = need
        keep = self.n_rows - row
        self._anc[:keep] = self._anc[row:self.n_rows]
        self._eid[:keep] = self._eid[row:self.n_rows]
        self._anc[keep:] = -1
        self._eid[keep:] = -1
        self.n_rows = keep

    # -- reading -------------------------------------------------------------------------------

    def assignments(self, particle: int, start: int = 0) -> IntArray:
        """Particle ``particle``'s expert id for every recorded point from ``start`` on, in
        order: O(N - start) (plus the rows since the lineages last met)."""
        start = min(max(0, int(start)), len(self))
        out = np.empty(len(self) - start, dtype=np.int64)
        head = max(0, self.n_settled - start)
        out[:head] = self._settled[start:self.n_settled]
        if self.n_rows:
            trace = jit.trace_assignments(self._anc, self._eid, self.n_rows, int(particle))
            out[head:] = trace[max(0, start - self.n_settled):]
        return out

    def settled_points(self) -> int:
        """Points whose assignment is the same in every particle and stays so: a lower bound,
        exact right after :meth:`settle`, which this runs once the rows have grown by a quarter
        (at least 16) since it last ran, so that asking at every step costs amortised O(P) even
        while two lineages stay apart for a long time (the walk back is O(rows))."""
        if len(self) - self._tried >= max(16, self.n_rows // 4):
            self.settle()
        return self.n_settled

    # -- state ---------------------------------------------------------------------------------

    def state(self) -> dict[str, np.ndarray]:
        """``history_settled`` (M,), ``history_ancestor`` and ``history_expert`` (N - M, P):
        canonical (settled as far as the lineages allow), so equal models give equal arrays."""
        self.settle()
        return {
            "history_settled": self._settled[:self.n_settled].copy(),
            "history_ancestor": self._anc[:self.n_rows].copy(),
            "history_expert": self._eid[:self.n_rows].copy(),
        }

    @classmethod
    def from_state(cls, width: int, settled: npt.ArrayLike | None, ancestors: npt.ArrayLike,
                   expert_ids: npt.ArrayLike) -> SegmentationHistory:
        """The history saved by :meth:`state` (``settled=None``: a schema-2 table, all rows)."""
        hist = cls(width)
        done = np.zeros(0, dtype=np.int64) if settled is None else np.asarray(settled, np.int64)
        anc = np.asarray(ancestors, dtype=np.int32).reshape(-1, width)
        eid = np.asarray(expert_ids, dtype=np.int64).reshape(-1, width)
        rows = max(_MIN_ROWS, 2 * anc.shape[0])
        hist._settled = _grown(done, max(_MIN_ROWS, done.size), 0)
        hist.n_settled = done.size
        hist._anc = _grown(anc, rows, -1)
        hist._eid = _grown(eid, rows, -1)
        hist.n_rows = anc.shape[0]
        hist.settle()
        return hist

    @property
    def nbytes(self) -> int:
        """Bytes held (allocated buffers, not only the rows in use)."""
        return int(self._settled.nbytes + self._anc.nbytes + self._eid.nbytes)


def _grown(arr: np.ndarray, rows: int, fill: int) -> np.ndarray:
    """``arr`` in a buffer of ``rows`` leading rows, the new rows set to ``fill``."""
    out = np.full((rows, *arr.shape[1:]), fill, dtype=arr.dtype)
    out[:arr.shape[0]] = arr
    return out
