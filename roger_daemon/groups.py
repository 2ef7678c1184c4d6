"""ROGER's experts merged per group: one expert per majority label (docs/goal-scoring.md,
"merged groups"; docs/learner-math.md §8).

The paper groups the learned experts by the subtask that generated most of their data and
lets the hand-coded transitioner act with a group (section IV.A). :func:`merge_groups` makes
each group one expert: the points ROGER's MAP particle gave to a group's experts are learned,
in their order, by one expert of a one-particle ROGER model
(:func:`roger_daemon.learner.partition.fit_partition`). ROGER's partition chooses the points;
the labels only name each expert's group (:mod:`roger_daemon.labels`), as for the
transitioner. The experiment (``groups:K``) and ``roger replay --merge-groups`` both call it.
"""

from __future__ import annotations

from collections.abc import Hashable, Mapping, Sequence
from typing import Any, TypeVar

import numpy as np
import numpy.typing as npt

from roger_daemon.labels import majority_labels
from roger_daemon.learner.partition import fit_partition

__all__ = ["merge_groups", "refit_groups"]

G = TypeVar("G", bound=Hashable)


def refit_groups(x: npt.ArrayLike, y: npt.ArrayLike, model: Any,
                 group_of_expert: Mapping[int, G], *, params: Any,
                 seed: int | None) -> tuple[Any, list[G]]:
    """``(refitted model, group of every point)``: the points a ROGER ``model`` learned from
    ``(x[i], y[i])``, in that order, each given the group of the expert its MAP particle
    assigned it to, learned by one expert per group (:func:`fit_partition`). The grouping is
    the caller's: by majority label (:func:`merge_groups`) or from the data alone
    (:mod:`roger_daemon.consolidate`).
    """
    assignments = np.asarray(model.assignments()).tolist()
    group_of_point = [group_of_expert[k] for k in assignments]
    return fit_partition(x, y, group_of_point, params=params, seed=seed), group_of_point


def merge_groups(x: npt.ArrayLike, y: npt.ArrayLike, labels: Sequence[str], model: Any, *,
                 params: Any, seed: int | None) -> tuple[Any, list[str]]:
    """``(merged model, group of every point)`` for a ROGER ``model`` that learned the pairs
    ``(x[i], y[i])`` labelled ``labels[i]``, in that order (its whole history).

    Raises ``ValueError`` if the counts disagree.
    """
    assignments = np.asarray(model.assignments()).tolist()
    if not len(assignments) == len(labels) == len(np.asarray(x)):
        raise ValueError(f"merge_groups: the model learned {len(assignments)} pairs; "
                         f"{len(labels)} labels and {len(np.asarray(x))} pairs were given")
    merged, group_of_point = refit_groups(x, y, model, majority_labels(assignments, labels),
                                          params=params, seed=seed)
    return merged, group_of_point
