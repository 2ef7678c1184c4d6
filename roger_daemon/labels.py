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
    rows = np.asarray(counts, dtype=np.int64)[:, :n_lab].tolist()
    if not rows or n_lab == 0:
        return {}
    order = _tie_order(names)
    return {int(e): _majority(row, order, names)
            for e, row in zip(np.asarray(ids).tolist(), rows, strict=True)}


def _tie_order(names: Sequence[str]) -> list[int]:
    """The columns that can win, in the order ties go: alphabetical, ``""`` left out."""
    return sorted((i for i, s in enumerate(names) if s), key=lambda i: names[i])


def _majority(row: Sequence[int], order: Sequence[int], names: Sequence[str]) -> str:
    """The rule for one expert's counts (``row[c]``: its points with code ``c``): the most
    frequent non-empty label, the first of ``order`` on a tie, ``""`` when none is counted."""
    best, most = "", 0
    width = len(row)
    for i in order:
        if i < width and row[i] > most:
            best, most = names[i], row[i]
    return best


class LabelTally:
    """Majority labels of a model that keeps learning, at a cost that does not grow with it.

    Keeps the label counts of every learned point under its current expert. A point's expert
    can change only while it is among the model's ``unsettled_points()`` (the points on which
    the particles' lineages disagree, and the last few steps: docs/learner-math.md §4.1); every
    other point is counted once, for good. At each call the tally reads the experts of the
    points that were unsettled at its last call, moves the counts of those whose expert changed,
    counts the points learned since, and applies the rule again to the experts whose counts
    moved. So labelling costs O(unsettled + new points), not O(points learned) (a day of
    demonstrations at 30 Hz is ~10^6 points). Gives exactly :func:`majority_labels_coded` of
    the whole history.
    """

    #: above this many points at once (a first call on a long history), counted by
    #: :func:`label_counts` in one vectorised pass instead of one point at a time
    vectorise_above = 64

    def __init__(self) -> None:
        self._clear(None)

    def _clear(self, model: Any) -> None:
        self._model = None if model is None else weakref.ref(model)
        self.counted = 0  # points counted (those in _open counted as _open_ids say)
        self._open = np.zeros(0, dtype=np.int64)  # the unsettled points at the last call
        self._open_ids = np.zeros(0, dtype=np.int64)  # ... and their experts then
        self._counts: dict[int, list[int]] = {}  # expert id -> points per code (experts now)
        self._labels: dict[int, str] = {}  # expert id -> its label under _names
        self._names: list[str] = []
        self._order: list[int] = []

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
        touched: set[int] = set()
        if moved.size:
            self._add(self._open_ids[moved], c[self._open[moved]], -1, touched)
        fresh = np.concatenate([moved, np.arange(n_open, recount.size)])
        if fresh.size:
            self._add(now[fresh], c[recount[fresh]], 1, touched)
        self._open = unsettled
        self._open_ids = now[recount.size:]
        self.counted = c.size
        names = [str(v) for v in vocab]
        if names != self._names:  # the vocabulary grew: every expert's label again
            self._names, self._order = names, _tie_order(names)
            touched = set(self._counts)
        for e in touched:
            row = self._counts.get(e)
            if row is None:
                self._labels.pop(e, None)
            else:
                self._labels[e] = _majority(row, self._order, names)
        if not names:
            return {}
        return dict(sorted(self._labels.items()))

    def _add(self, ids: npt.NDArray[np.int64], codes: npt.NDArray[np.int64], sign: int,
             touched: set[int]) -> None:
        """Count (``sign`` 1) or take back (-1) points of experts ``ids`` with ``codes``."""
        if ids.size > self.vectorise_above:
            uniq, counts = label_counts(ids, codes, int(codes.max()) + 1)
            pairs = [(e, code, n) for e, row in zip(uniq.tolist(), counts.tolist(), strict=True)
                     for code, n in enumerate(row) if n]
        else:
            pairs = [(e, code, 1) for e, code in zip(ids.tolist(), codes.tolist(), strict=True)]
        for e, code, n in pairs:
            row = self._counts.setdefault(e, [])
            if code >= len(row):
                row.extend([0] * (code + 1 - len(row)))
            row[code] += sign * n
            touched.add(e)
        for e in touched:
            if e in self._counts and not any(self._counts[e]):  # no point left: forgotten
                del self._counts[e]


def _within(points: npt.NDArray[np.int64], open_points: npt.NDArray[np.int64],
            counted: int) -> bool:
    """Whether every one of ``points`` was unsettled at the last call or is new since (a point
    counted as settled never becomes unsettled again, unless the model was replaced)."""
    old = points[points < counted]
    return old.size == 0 or set(old.tolist()) <= set(open_points.tolist())


def majority_labels(assignments: npt.ArrayLike, labels: Sequence[str]) -> dict[int, str]:
    """Expert id -> the majority non-empty label of its points (module docstring: the rule).

    >>> majority_labels([0, 0, 1, 1, 1], ["trap", "aim", "", "seek", "seek"])
    {0: 'aim', 1: 'seek'}
    """
    labs = [str(s) for s in labels]
    vocab = sorted(set(labs))
    index = {s: i for i, s in enumerate(vocab)}
    return majority_labels_coded(assignments, [index[s] for s in labs], vocab)
