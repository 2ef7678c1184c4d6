"""Label-free consolidation of ROGER's experts by the temporal continuity of the policy
(issue 59, "fewer, truer experts"; docs/goal-scoring.md, "Consolidation by continuity").

ROGER's Gaussian gates split one subtask into several experts along perception dimensions
its policy ignores. Within a subtask the demonstrator's command is continuous in time, so
when the MAP particle's assignment switches between two experts of one subtask at
*consecutive* ticks of one demonstration, the command barely moves; a switch between
subtasks (trap, kick, walk) coincides with a command discontinuity. :func:`continuity_groups`
builds a graph over experts from the switches between truly consecutive ticks (same
location, tick difference 1: the downsampled stream has gaps), links two experts whose
switches are mostly continuous, and returns its connected components.
:func:`consolidate` then refits one expert per component with
:func:`roger_daemon.learner.partition.fit_partition`, exactly as
:func:`roger_daemon.groups.merge_groups` does for label groups, but with groups from the
data alone: the demonstrator's labels never enter (they may afterwards name the groups for
the transitioner). With consolidation off, the model is the paper's Algorithm 1 untouched.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from roger_daemon.groups import refit_groups

__all__ = ["ContinuityRule", "command_groups", "consolidate", "continuity_groups"]


@dataclass(frozen=True)
class ContinuityRule:
    """When a switch is continuous, and when two experts are linked.

    ``quantile``: the jump scale is this quantile of the within-expert command steps between
    consecutive ticks (max over outputs of ``|y_t - y_{t-1}| / y_scale``); ``factor`` times it
    (at least ``floor``) is the threshold of a continuous switch. Two experts are linked when
    at least ``min_count`` switches between them are continuous and those are at least
    ``min_share`` of all their switches.
    """

    quantile: float = 0.95
    factor: float = 1.0
    floor: float = 1e-6
    min_count: int = 3
    min_share: float = 0.5

    def __post_init__(self) -> None:
        if not 0.0 <= self.quantile <= 1.0:
            raise ValueError(f"quantile must be in [0, 1], got {self.quantile}")
        if self.factor <= 0 or self.floor < 0 or self.min_count < 1:
            raise ValueError("factor > 0, floor >= 0 and min_count >= 1 expected")
        if not 0.0 <= self.min_share <= 1.0:
            raise ValueError(f"min_share must be in [0, 1], got {self.min_share}")


def _switches(assignments: npt.NDArray[np.int64], y: npt.NDArray[np.float64],
              location: npt.NDArray[np.int64], tick: npt.NDArray[np.int64],
              y_scale: npt.NDArray[np.float64], rule: ContinuityRule
              ) -> tuple[Counter[tuple[int, int]], Counter[tuple[int, int]]]:
    """(continuous, discontinuous) switch counts per unordered expert pair."""
    consecutive = (location[1:] == location[:-1]) & (tick[1:] - tick[:-1] == 1)
    jump = np.max(np.abs(np.diff(y, axis=0)) / y_scale, axis=1)
    same = assignments[1:] == assignments[:-1]
    within = jump[consecutive & same]
    scale = float(np.quantile(within, rule.quantile)) if within.size else 0.0
    threshold = max(rule.factor * scale, rule.floor)
    cont: Counter[tuple[int, int]] = Counter()
    disc: Counter[tuple[int, int]] = Counter()
    for t in np.flatnonzero(consecutive & ~same):
        i, j = int(assignments[t]), int(assignments[t + 1])
        (cont if jump[t] <= threshold else disc)[(min(i, j), max(i, j))] += 1
    return cont, disc


def continuity_groups(assignments: npt.ArrayLike, y: npt.ArrayLike, location: npt.ArrayLike,
                      tick: npt.ArrayLike, *, y_scale: npt.ArrayLike | None,
                      rule: ContinuityRule | None = None) -> dict[int, int]:
    """Expert id -> group id (the smallest expert id of its connected component).

    ``assignments`` the MAP particle's expert of every point in stream order, ``y`` the
    commands, ``location`` and ``tick`` each point's demonstration and tick (only switches
    between consecutive ticks of one demonstration count).

    >>> a = [0, 0, 1, 1, 2, 2]
    >>> y = [[0.0], [0.1], [0.2], [0.3], [5.0], [5.1]]
    >>> continuity_groups(a * 3, y * 3, [0] * 18, list(range(18)), y_scale=[1.0],
    ...                   rule=ContinuityRule(min_count=2))
    {0: 0, 1: 0, 2: 2}
    """
    rule = rule or ContinuityRule()
    a = np.asarray(assignments, dtype=np.int64).reshape(-1)
    ya = np.asarray(y, dtype=np.float64).reshape(len(a), -1)
    loc = np.asarray(location, dtype=np.int64).reshape(-1)
    tk = np.asarray(tick, dtype=np.int64).reshape(-1)
    if not len(a) == len(loc) == len(tk):
        raise ValueError(f"continuity_groups: {len(a)} assignments, {len(loc)} locations and "
                         f"{len(tk)} ticks given")
    scale = np.broadcast_to(np.asarray(1.0 if y_scale is None else y_scale, dtype=np.float64),
                            (ya.shape[1],))
    cont, disc = _switches(a, ya, loc, tk, scale, rule)
    parent = {int(k): int(k) for k in np.unique(a)}

    def find(k: int) -> int:
        while parent[k] != k:
            parent[k] = parent[parent[k]]
            k = parent[k]
        return k

    for pair in sorted(cont):
        c, d = cont[pair], disc[pair]
        if c >= rule.min_count and c >= rule.min_share * (c + d):
            ri, rj = find(pair[0]), find(pair[1])
            parent[max(ri, rj)] = min(ri, rj)
    return {k: find(k) for k in sorted(parent)}


def command_groups(assignments: npt.ArrayLike, y: npt.ArrayLike, *,
                   y_scale: npt.ArrayLike | None, tau: float) -> dict[int, int]:
    """Expert id -> group id (smallest expert id of its cluster): complete-linkage clusters
    of the experts' median commands (scaled by ``y_scale``, Chebyshev distance) at ``tau``.

    >>> command_groups([0, 0, 1, 1, 2, 2], [[0.0], [0.1], [0.02], [0.1], [1.0], [1.1]],
    ...                y_scale=None, tau=0.05)
    {0: 0, 1: 0, 2: 2}
    """
    from scipy.cluster.hierarchy import fcluster, linkage

    a = np.asarray(assignments, dtype=np.int64).reshape(-1)
    ya = np.asarray(y, dtype=np.float64).reshape(len(a), -1)
    scale = np.broadcast_to(np.asarray(1.0 if y_scale is None else y_scale, dtype=np.float64),
                            (ya.shape[1],))
    ids = [int(k) for k in np.unique(a)]
    if len(ids) < 2:
        return {k: k for k in ids}
    med = np.array([np.median(ya[a == k] / scale, axis=0) for k in ids])
    cluster = fcluster(linkage(med, method="complete", metric="chebyshev"), tau,
                       criterion="distance")
    first: dict[int, int] = {}
    for k, c in zip(ids, cluster.tolist(), strict=True):
        first.setdefault(int(c), k)
    return {k: first[int(c)] for k, c in zip(ids, cluster.tolist(), strict=True)}


def consolidate(x: npt.ArrayLike, y: npt.ArrayLike, location: npt.ArrayLike,
                tick: npt.ArrayLike, model: Any, *, params: Any, seed: int | None,
                rule: ContinuityRule | None = None) -> tuple[Any, list[int]]:
    """``(consolidated model, group of every point)`` for a ROGER ``model`` that learned the
    pairs ``(x[i], y[i])`` in that order (its whole history): one expert per continuity
    group, refitted in stream order by :func:`~roger_daemon.groups.refit_groups`.
    """
    assignments = np.asarray(model.assignments(), dtype=np.int64).reshape(-1)
    if len(assignments) != len(np.asarray(x)):
        raise ValueError(f"consolidate: the model learned {len(assignments)} pairs; "
                         f"{len(np.asarray(x))} were given")
    group_of = continuity_groups(assignments, y, location, tick,
                                 y_scale=params.y_scale, rule=rule)
    return refit_groups(x, y, model, group_of, params=params, seed=seed)
