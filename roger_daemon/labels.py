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

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

__all__ = ["majority_labels", "majority_labels_coded"]


def majority_labels_coded(assignments: npt.ArrayLike, codes: npt.ArrayLike,
                          vocab: Sequence[str]) -> dict[int, str]:
    """:func:`majority_labels` for labels stored as integer ``codes`` into ``vocab`` (the
    daemon's and the checkpoints' form), in one vectorised pass."""
    a = np.asarray(assignments, dtype=np.int64).reshape(-1)
    c = np.asarray(codes, dtype=np.int64).reshape(-1)
    if a.size != c.size:
        raise ValueError(f"{a.size} assignments but {c.size} labels")
    if a.size == 0 or not vocab:
        return {}
    names = [str(v) for v in vocab]
    ids, inv = np.unique(a, return_inverse=True)
    n_lab = len(names)
    counts = np.bincount(inv * n_lab + c, minlength=ids.size * n_lab).reshape(ids.size, n_lab)
    if "" in names:
        counts[:, names.index("")] = 0
    alpha = sorted(range(n_lab), key=lambda i: names[i])  # ties: first by name
    best = counts[:, alpha].argmax(axis=1)
    has = counts.max(axis=1) > 0
    return {int(e): (names[alpha[int(b)]] if h else "")
            for e, b, h in zip(ids, best, has, strict=True)}


def majority_labels(assignments: npt.ArrayLike, labels: Sequence[str]) -> dict[int, str]:
    """Expert id -> the majority non-empty label of its points (module docstring: the rule).

    >>> majority_labels([0, 0, 1, 1, 1], ["trap", "aim", "", "seek", "seek"])
    {0: 'aim', 1: 'seek'}
    """
    labs = [str(s) for s in labels]
    vocab = sorted(set(labs))
    index = {s: i for i, s in enumerate(vocab)}
    return majority_labels_coded(assignments, [index[s] for s in labs], vocab)
