"""Consolidation by continuity (roger_daemon/consolidate.py): groups from the data alone."""

from __future__ import annotations

import numpy as np
import pytest

from roger_daemon.consolidate import ContinuityRule, consolidate, continuity_groups
from roger_daemon.learner import RogerParams
from roger_daemon.learner.partition import fit_partition


def _stream(gap: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Three demonstrations of 60 ticks. The policy f(t) = sin(t / 10) is split by an
    irrelevant input (x[:, 1], its sign flips every 5 ticks) into experts 0 and 1; the other
    branch of a multimap, -f - 1, is expert 2, entered with a jump."""
    rows = []
    for loc in range(3):
        for k in range(60):
            t = k * gap
            branch = (k // 20) % 2 == 1  # ticks 20-39 on the -f branch
            f = np.sin(t / 10.0)
            side = 1.0 if (k // 5) % 2 == 0 else -1.0
            expert = 2 if branch else (0 if side > 0 else 1)
            y = -f - 1.0 if branch else f
            rows.append((loc, t, expert, [np.cos(t / 10.0), side], [y]))
    loc_, tick, a, x, y = (np.array([r[i] for r in rows]) for i in range(5))
    return x.astype(float), y.astype(float), loc_, tick, a


def test_experts_splitting_one_smooth_policy_are_joined_and_a_multimap_branch_is_not() -> None:
    x, y, loc, tick, a = _stream()
    groups = continuity_groups(a, y, loc, tick, y_scale=[1.0])
    assert groups == {0: 0, 1: 0, 2: 2}


def test_only_switches_between_consecutive_ticks_count() -> None:
    """The same switches with gaps of 2 ticks between the points (a downsampled stream):
    no pair of points is consecutive, so nothing is linked."""
    x, y, loc, tick, a = _stream(gap=2)
    assert continuity_groups(a, y, loc, tick, y_scale=[1.0]) == {0: 0, 1: 1, 2: 2}


def test_a_pair_needs_min_count_continuous_switches() -> None:
    x, y, loc, tick, a = _stream()
    many = ContinuityRule(min_count=10_000)
    assert continuity_groups(a, y, loc, tick, y_scale=[1.0], rule=many) == {0: 0, 1: 1, 2: 2}


class _Assigned:
    """A stand-in for a trained ROGER model: consolidate reads only its assignments."""

    def __init__(self, a: np.ndarray) -> None:
        self.a = a

    def assignments(self) -> np.ndarray:
        return self.a


def test_consolidate_refits_one_expert_per_group_in_stream_order() -> None:
    x, y, loc, tick, a = _stream()
    params = RogerParams(nu0=4.0, theta_w=1.0, particles=5)
    model, group_of_point = consolidate(x, y, loc, tick, _Assigned(a), params=params, seed=0)
    assert group_of_point == [0 if k in (0, 1) else 2 for k in a.tolist()]
    want = fit_partition(x, y, group_of_point, params=params, seed=0)
    assert model.n_experts == 2
    got, ref = model.state_dict(), want.state_dict()
    assert sorted(got) == sorted(ref)
    for key in ref:
        np.testing.assert_array_equal(got[key], ref[key])


def test_bad_rule_and_sizes_raise() -> None:
    with pytest.raises(ValueError, match="quantile"):
        ContinuityRule(quantile=1.5)
    x, y, loc, tick, a = _stream()
    with pytest.raises(ValueError, match="assignments"):
        continuity_groups(a[:-1], y[:-1], loc, tick, y_scale=None)
