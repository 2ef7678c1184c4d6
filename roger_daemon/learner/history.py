"""ROGER's segmentation history: which expert each particle gave every learned point.

Each step appends one row: for each survivor, the index of its ancestor among the previous
step's particles and the id of the expert it put the point in (paper Algorithm 1).  Tracing a
final particle back through the ancestors gives its assignment of every point
(:meth:`SegmentationHistory.assignments`).

Only a short *window* of rows (at most :data:`WINDOW` steps) is kept per particle.  When it
fills, every row but the last is *settled* (docs/learner-math.md §4.1): the lineages of the
present particles are traced back to the start of the window, and each settled point keeps one
expert id (8 bytes) if all those lineages agree on it, or becomes an *exception*: a row of
per-lineage ids, one per particle present at the end of the settled part (the *boundary*).
A later particle reaches its boundary particle through the window, so its assignment of every
point is recovered exactly.  At each settle the exceptions are re-read through the new boundary:
where the surviving lineages have come to agree (the others died out), the point is settled for
good.  Memory: 8 B per point plus ``8 (P + 1)`` B per point on which surviving lineages still
disagree (a handful: lineages differ on few points, and rarely for long) plus the fixed window,
so it no longer depends on how long two lineages stay apart.

The settled form is canonical after :meth:`settle` (which :meth:`state` runs): the exceptions
are exactly the points on which the present lineages disagree and the boundary is the last
row's ancestors, whatever was settled before, so a state dict does not depend on when the model
was saved or restored.  Exact: property-tested against a naive trace of the full table
(``tests/learner/test_history.py``).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.engine import jit

__all__ = ["WINDOW", "SegmentationHistory"]

IntArray = npt.NDArray[np.int64]
AncArray = npt.NDArray[np.int32]

#: rows kept per particle before they are settled (a settle costs O(WINDOW P + K P) for K
#: exceptions, so amortised O(P + K P / WINDOW) per step)
WINDOW = 64
_MIN_POINTS = 64


class SegmentationHistory:
    """Per-step (ancestor, chosen expert id) of each survivor: a fixed window of rows, the
    points before it settled to one id each plus per-lineage exceptions (module docstring)."""

    def __init__(self, width: int) -> None:
        self.width = int(width)
        self._settled = np.full(_MIN_POINTS, -1, dtype=np.int64)  # -1 at exception points
        self.n_settled = 0
        self._xpt = np.zeros(0, dtype=np.int64)  # exception points, ascending
        self._xid = np.zeros((0, self.width), dtype=np.int64)  # their id per boundary particle
        self._anc = np.full((WINDOW, self.width), -1, dtype=np.int32)
        self._eid = np.full((WINDOW, self.width), -1, dtype=np.int64)
        self.n_rows = 0  # window rows in use (the points from n_settled on)

    def __len__(self) -> int:
        return self.n_settled + self.n_rows

    # -- learning ------------------------------------------------------------------------------

    def append(self, ancestors: npt.ArrayLike, expert_ids: npt.ArrayLike) -> None:
        """Record one step: survivor ``j`` descends from particle ``ancestors[j]`` of the previous
        step and put the point in expert ``expert_ids[j]``.  Amortised O(P + K P / WINDOW)."""
        if self.n_rows == self._anc.shape[0]:
            self.settle()
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
        """Settle every window row but the last (module docstring).  Changes no assignment."""
        rows = self.n_rows - 1
        if rows <= 0:
            return
        alive = int(np.count_nonzero(self._eid[rows] >= 0))
        boundary = np.unique(self._anc[rows, :alive]).astype(np.int64)  # particles at row - 1
        ids, origin = jit.trace_lineages(self._anc, self._eid, rows, boundary)
        old = self._xid[:, origin]  # each boundary lineage's ids at the old exceptions
        points = np.concatenate([self._xpt, self.n_settled + np.arange(rows, dtype=np.int64)])
        values = np.concatenate([old, ids])  # (K + rows, |boundary|)
        agree = np.all(values == values[:, :1], axis=1)
        need = self.n_settled + rows
        if need > self._settled.size:
            self._settled = _grown(self._settled, max(need, 2 * self._settled.size), -1)
        self._settled[points[agree]] = values[agree, 0]
        self._settled[points[~agree]] = -1
        self.n_settled = need
        self._xpt = points[~agree]
        self._xid = np.full((self._xpt.size, self.width), -1, dtype=np.int64)
        self._xid[:, boundary] = values[~agree]
        self._anc[0] = self._anc[rows]
        self._eid[0] = self._eid[rows]
        self._anc[1:] = -1
        self._eid[1:] = -1
        self.n_rows = 1

    # -- reading -------------------------------------------------------------------------------

    def _trace(self, particle: int) -> tuple[IntArray, int]:
        """Particle ``particle``'s ids over the window and its boundary ancestor."""
        ids, origin = jit.trace_lineages(self._anc, self._eid, self.n_rows,
                                         np.array([particle], dtype=np.int64))
        return ids[:, 0], int(origin[0])

    def assignments(self, particle: int, start: int = 0) -> IntArray:
        """Particle ``particle``'s expert id for every recorded point from ``start`` on, in
        order: O(N - start + K + WINDOW)."""
        start = min(max(0, int(start)), len(self))
        out = np.empty(len(self) - start, dtype=np.int64)
        if self.n_rows == 0:
            out[:] = self._settled[start:self.n_settled]
            return out
        window, origin = self._trace(int(particle))
        head = max(0, self.n_settled - start)
        out[:head] = self._settled[start:self.n_settled]
        mine = self._xpt >= start
        out[self._xpt[mine] - start] = self._xid[mine, origin]
        out[head:] = window[max(0, start - self.n_settled):]
        return out

    def unsettled_points(self) -> IntArray:
        """The points whose expert may still change: the exceptions and the window, ascending.
        Every other point's expert is the same in every particle, now and after any further
        learning."""
        window = np.arange(self.n_settled, len(self), dtype=np.int64)
        return np.concatenate([self._xpt, window])

    def assignments_at(self, particle: int, points: npt.ArrayLike) -> IntArray:
        """Particle ``particle``'s expert id at each of ``points`` (indices < len(self)):
        O(len(points) log K + WINDOW) in one compiled call
        (:func:`.jit_particles.lineage_assignments`)."""
        idx = np.ascontiguousarray(points, dtype=np.int64).reshape(-1)
        if idx.size and (idx.min() < 0 or idx.max() >= len(self)):
            raise IndexError(f"points must be in [0, {len(self)})")
        out: IntArray = jit.lineage_assignments(idx, self._settled, self.n_settled, self._anc,
                                                self._eid, self.n_rows, int(particle),
                                                self._xpt, self._xid)
        return out

    # -- state ---------------------------------------------------------------------------------

    def state(self) -> dict[str, np.ndarray]:
        """``history_settled`` (M,), ``history_exception_points`` (K,) and
        ``history_exception_ids`` (K, P), ``history_ancestor`` and ``history_expert`` (the last
        row, (1, P)): canonical (settled), so equal models give equal arrays.

        Reads only: a settled copy is saved, this history is left as it is, so threads may
        save one model at once (the experiment's daemon check beside its checkpoints did, and
        two concurrent settles counted the window twice)."""
        hist = self._copy()
        hist.settle()
        return {
            "history_settled": hist._settled[:hist.n_settled],
            "history_exception_points": hist._xpt,
            "history_exception_ids": hist._xid,
            "history_ancestor": hist._anc[:hist.n_rows],
            "history_expert": hist._eid[:hist.n_rows],
        }

    def _copy(self) -> SegmentationHistory:
        """An independent copy (of the rows in use)."""
        out = SegmentationHistory(self.width)
        out._settled = self._settled[:max(self.n_settled, _MIN_POINTS)].copy()
        out.n_settled = self.n_settled
        out._xpt = self._xpt.copy()
        out._xid = self._xid.copy()
        out._anc = self._anc.copy()
        out._eid = self._eid.copy()
        out.n_rows = self.n_rows
        return out

    @classmethod
    def from_state(cls, width: int, settled: npt.ArrayLike | None, ancestors: npt.ArrayLike,
                   expert_ids: npt.ArrayLike, exception_points: npt.ArrayLike | None = None,
                   exception_ids: npt.ArrayLike | None = None) -> SegmentationHistory:
        """The history saved by :meth:`state`; ``settled=None`` is a schema-2 table (all rows),
        no exceptions a schema-3 one (settled where the lineages met, the window after)."""
        hist = cls(width)
        done = np.zeros(0, dtype=np.int64) if settled is None else np.asarray(settled, np.int64)
        anc = np.asarray(ancestors, dtype=np.int32).reshape(-1, width)
        eid = np.asarray(expert_ids, dtype=np.int64).reshape(-1, width)
        hist._settled = _grown(done, max(_MIN_POINTS, done.size), -1)
        hist.n_settled = done.size
        if exception_points is not None and exception_ids is not None:
            hist._xpt = np.asarray(exception_points, dtype=np.int64).reshape(-1).copy()
            hist._xid = np.asarray(exception_ids, dtype=np.int64).reshape(-1, width).copy()
        if anc.shape[0] > WINDOW:  # an older state's long window: settled once, in one go
            hist._anc = anc.copy()
            hist._eid = eid.copy()
            hist.n_rows = anc.shape[0]
            hist.settle()
            hist._anc = _grown(hist._anc[:1], WINDOW, -1)
            hist._eid = _grown(hist._eid[:1], WINDOW, -1)
        else:
            hist._anc[:anc.shape[0]] = anc
            hist._eid[:eid.shape[0]] = eid
            hist.n_rows = anc.shape[0]
        hist.settle()
        return hist

    @property
    def n_exceptions(self) -> int:
        """Settled points on which the present lineages still disagree."""
        return int(self._xpt.size)

    @property
    def nbytes(self) -> int:
        """Bytes held (allocated buffers, not only the rows in use)."""
        return int(self._settled.nbytes + self._xpt.nbytes + self._xid.nbytes
                   + self._anc.nbytes + self._eid.nbytes)


def _grown(arr: np.ndarray, rows: int, fill: int) -> np.ndarray:
    """``arr`` in a buffer of ``rows`` leading rows, the new rows set to ``fill``."""
    out = np.empty((rows, *arr.shape[1:]), dtype=arr.dtype)
    out[:arr.shape[0]] = arr
    out[arr.shape[0]:] = fill
    return out
