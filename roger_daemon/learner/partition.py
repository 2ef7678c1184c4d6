"""ROGER on a given partition: one particle whose experts are named groups of the points.

The paper groups the learned experts by the subtask that generated most of their data and
lets a transitioner pick within a group (section IV.A). :func:`fit_partition` builds the
model in which each group is *one* expert: a ROGER model with a single particle, where point
``i`` joins the expert of ``groups[i]`` (a new expert for a group's first point) through the
same step as Algorithm 1 (:meth:`.Roger.learn_assigned`: SOGP and NIW gate updated exactly
as when the particle filter chooses that expert). The result is an ordinary :class:`.Roger`
(``state_dict``, predictions, ``assignments``), so the daemon serves it like any other model.
docs/learner-math.md §8 and docs/goal-scoring.md ("merged groups") say what it is for.
"""

from __future__ import annotations

from collections.abc import Hashable, Sequence
from dataclasses import replace

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.model_args import Seed
from roger_daemon.learner.params import RogerParams
from roger_daemon.learner.roger import Roger

__all__ = ["fit_partition"]


def fit_partition(x: npt.ArrayLike, y: npt.ArrayLike, groups: Sequence[Hashable], *,
                  params: RogerParams, seed: Seed = None) -> Roger:
    """A one-particle :class:`Roger` whose experts are the groups of ``groups``, in order of
    first appearance; expert ids are 0, 1, ... in that order.

    ``params`` as for ROGER (``particles`` is set to 1: the partition is given, not searched).

    >>> import numpy as np
    >>> xs = np.linspace(-1, 1, 8)[:, None]
    >>> model = fit_partition(xs, np.sign(xs), ["a", "b"] * 4, params=RogerParams(), seed=0)
    >>> model.n_experts, model.assignments().tolist()
    (2, [0, 1, 0, 1, 0, 1, 0, 1])
    """
    xa = np.asarray(x, dtype=np.float64)
    ya = np.asarray(y, dtype=np.float64)
    if xa.ndim != 2 or ya.ndim != 2 or len(xa) != len(ya) or len(xa) != len(groups):
        raise ValueError(f"fit_partition: x (n, d_x), y (n, d_y) and n groups expected, got "
                         f"x {xa.shape}, y {ya.shape} and {len(groups)} groups")
    model = Roger(d_x=xa.shape[1], d_y=ya.shape[1], params=replace(params, particles=1),
                  seed=seed)
    expert_of: dict[Hashable, int] = {}
    for xi, yi, group in zip(xa, ya, groups, strict=True):
        # the putative that puts the point into its group's expert (None: a new expert)
        expert_of[group] = model.learn_assigned(xi, yi, expert_of.get(group))
    return model
