"""The majority-label rule: which subtask each expert stands for (the one owner of the rule).

The demonstrator's labels never enter learning; they only name experts afterwards, for the
transitioner (which picks among the experts of its current subtask) and for scoring the
segmentation. The daemon, replay, recovery and the experiment all call this module, so they can
never disagree on a name.

Rule: an expert's label is the most frequent non-empty label among the points assigned to it;
``""`` if none of its points is labelled. Ties go to the label first in alphabetical order, which
does not depend on the order the labels arrived in (a checkpoint's vocabulary, a replay started
mid-session and an offline model all agree).
"""

from __future__ import annotations

import weakref
from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

__all__ = ["LabelTally", "label_counts", "majority_labels", "majority_labels_coded",
           "majority_of_counts"]


def majority_labels_coded(assignments: npt.ArrayLike, codes: npt.ArrayLike,
                          vocab: Sequence[str]) -> dict[int, str]:
    """:func:`majority_labels` for labels stored as integer ``codes`` into ``vocab`` (the
    daemon's and the checkpoints' form), in one vectorised pass."""
    if not vocab:
        _check_sizes(assignments, codes)
        return {}
    ids, counts = label_counts(assignments, codes, len(vocab))
    return majority_of_counts(ids, counts, vocab)


def _check_sizes(assignments: npt.ArrayLike, codes: npt.ArrayLike
                 ) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    a = np.asarray(assignments, dtype=np.int64).reshape(-1)
    c = np.asarray(codes, dtype=np.int64).reshape(-1)
    if a.size != c.size:
        raise ValueError(f"{a.size} assignments but {c.size} labels")
    return a, c


def label_counts(assignments: npt.ArrayLike, codes: npt.ArrayLike, n_labels: int
                 ) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """``(expert ids, counts)``: ``counts[i, c]`` points of expert ``ids[i]`` with code ``c``."""
    a, c = _check_sizes(assignments, codes)
    if a.size == 0:
        return np.zeros(0, dtype=np.int64), np.zeros((0, n_labels), dtype=np.int64)
    ids, inv = np.unique(a, return_inverse=True)
    counts = np.bincount(inv * n_labels + c, minlength=ids.size * n_labels)
    return ids, counts.reshape(ids.size, n_labels)


def majority_of_counts(ids: npt.ArrayLike, counts: npt.NDArray[np.int64],
                       vocab: Sequence[str]) -> dict[int, str]:
    """The rule (module docstring) applied to per-expert label counts (columns: ``vocab``)."""
    names = [str(v) for v in vocab]
    n_lab = len(names)
    counts = np.array(counts[:, :n_lab], dtype=np.int64)
    if counts.shape[0] == 0 or n_lab == 0:
        return {}
    if "" in names:
        counts[:, names.index("")] = 0
    alpha = sorted(range(n_lab), key=lambda i: names[i])  # ties: first by name
    best = counts[:, alpha].argmax(axis=1)
    has = counts.max(axis=1) > 0
    return {int(e): (names[alpha[int(b)]] if h else "")
            for e, b, h in zip(np.asarray(ids).tolist(), best, has, strict=True)}


class LabelTally:
    """Majority labels of a model that keeps learning, at a cost that does not grow with it.

    Keeps the label counts of every learned point under its current expert. A point's expert
    can change only while it is among the model's ``unsettled_points()`` (the points on which
    the particles' lineages disagree, and the last few steps: docs/learner-math.md §4.1); every
    other point is counted once, for good. At each call the tally reads the experts of the
    points that were unsettled at its last call, moves the counts of those whose expert changed,
    and counts the points learned since. So labelling costs O(unsettled + new points), not
    O(points learned) (a day of demonstrations at 30 Hz is ~10^6 points). Gives exactly
    :func:`majority_labels_coded` of the whole history.
    """

    forget_after = 64  # experts left with no point are dropped from the table beyond this many

    def __init__(self) -> None:
        self._clear(None)

    def _clear(self, model: Any) -> None:
        self._model = None if model is None else weakref.ref(model)
        self.counted = 0  # points counted (those in _open counted as _open_ids say)
        self._open = np.zeros(0, dtype=np.int64)  # the unsettled points at the last call
        self._open_ids = np.zeros(0, dtype=np.int64)  # ... and their experts then
        self._row: dict[int, int] = {}
        self._counts = np.zeros((0, 0), dtype=np.int64)  # every point, under its expert now

    def labels(self, model: Any, codes: npt.ArrayLike, vocab: Sequence[str]) -> dict[int, str]:
        """Expert id -> majority label; ``codes`` (one per learned point) index ``vocab``."""
        c = np.asarray(codes, dtype=np.int64).reshape(-1)
        unsettled = np.asarray(model.unsettled_points(), dtype=np.int64)
        unsettled = unsettled[unsettled < c.size]  # codes given for the first c.size points
        if self._model is None or self._model() is not model or c.size < self.counted \
                or not _within(unsettled, self._open, self.counted):
            self._clear(model)  # another model (a reset, a reload): count afresh
        # what may have changed since the last call, and the points learned since
        recount = np.concatenate([self._open, np.arange(self.counted, c.size, dtype=np.int64)])
        now = np.asarray(model.assignments_at(np.concatenate([recount, unsettled])), np.int64)
        n_open = self._open.size
        moved = np.flatnonzero(now[:n_open] != self._open_ids)  # expert changed: take back
        if moved.size:
            ids, counts = label_counts(self._open_ids[moved], c[self._open[moved]], len(vocab))
            self._add(ids, -counts)
        fresh = np.concatenate([moved, np.arange(n_open, recount.size)])
        if fresh.size:
            self._add(*label_counts(now[fresh], c[recount[fresh]], len(vocab)))
        self._open = unsettled
        self._open_ids = now[recount.size:]
        self.counted = c.size
        rows = sorted(self._row.items())
        table = np.zeros((len(rows), max(len(vocab), self._counts.shape[1])), dtype=np.int64)
        if rows:
            table[:, :self._counts.shape[1]] = self._counts[[r for _, r in rows]]
        present = table.sum(axis=1) > 0  # experts with points (not only ever seen)
        ids_all = np.array([e for e, _ in rows], dtype=np.int64)
        if np.count_nonzero(~present) > max(self.forget_after, len(rows) // 2):  # now empty
            self._row = {int(e): i for i, e in enumerate(ids_all[present].tolist())}
            self._counts = table[present].copy()
        return majority_of_counts(ids_all[present], table[present], vocab)

    def _add(self, ids: npt.NDArray[np.int64], counts: npt.NDArray[np.int64]) -> None:
        if ids.size == 0:
            return
        width = max(counts.shape[1], self._counts.shape[1])
        fresh = [int(e) for e in ids.tolist() if int(e) not in self._row]
        for e in fresh:
            self._row[e] = len(self._row)
        if width > self._counts.shape[1] or len(self._row) > self._counts.shape[0]:
            grown = np.zeros((max(len(self._row), 2 * self._counts.shape[0]), width),
                             dtype=np.int64)
            grown[:self._counts.shape[0], :self._counts.shape[1]] = self._counts
            self._counts = grown
        rows = np.array([self._row[int(e)] for e in ids.tolist()], dtype=np.int64)
        self._counts[rows, :counts.shape[1]] += counts


def _within(points: npt.NDArray[np.int64], open_points: npt.NDArray[np.int64],
            counted: int) -> bool:
    """Whether every one of ``points`` was unsettled at the last call or is new since (a point
    counted as settled never becomes unsettled again, unless the model was replaced)."""
    old = points[points < counted]
    if old.size == 0:
        return True
    pos = np.searchsorted(open_points, old)
    return bool(np.all(pos < open_points.size)
                and np.array_equal(open_points[np.minimum(pos, open_points.size - 1)], old))


def majority_labels(assignments: npt.ArrayLike, labels: Sequence[str]) -> dict[int, str]:
    """Expert id -> the majority non-empty label of its points (module docstring: the rule).

    >>> majority_labels([0, 0, 1, 1, 1], ["trap", "aim", "", "seek", "seek"])
    {0: 'aim', 1: 'seek'}
    """
    labs = [str(s) for s in labels]
    vocab = sorted(set(labs))
    index = {s: i for i, s in enumerate(vocab)}
    return majority_labels_coded(assignments, [index[s] for s in labs], vocab)
