"""Which thread takes which expert (roger_daemon/learner/engine/jit_batch.py, ``balanced_owners``).

Each expert keeps the thread that took it last (its home) so that its matrices stay in that
core's caches (docs/performance.md, *The slow spells are the two cores far apart*). Which
thread computes an expert must never change a float: learning is compared bit for bit across
owner assignments, and the assignment itself with exact cases and a brute-force oracle.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from roger_daemon.learner import Roger, RogerParams
from roger_daemon.learner.engine import jit
from roger_daemon.learner.synthetic import subtask_stream

from .batched import learn_stream

_I64 = np.int64


def _owners(homes: list[int], work: list[int], groups: int, rebalance: bool = True
            ) -> list[int]:
    got = jit.balanced_owners(np.array(homes, dtype=_I64), np.array(work, dtype=_I64),
                              groups, rebalance)
    return [int(v) for v in got]


def _loads(owners: list[int], work: list[int], groups: int) -> list[int]:
    return [sum(w for o, w in zip(owners, work, strict=True) if o == g) for g in range(groups)]


def test_balanced_homes_are_kept() -> None:
    assert _owners([0, 1, 1, 0, 1, 0], [3] * 6, 2) == [0, 1, 1, 0, 1, 0]
    assert _owners([1, 0, 2], [5, 5, 5], 3) == [1, 0, 2]


def test_experts_without_a_home_go_to_the_least_loaded_thread_in_order() -> None:
    # loads after the homed experts: [4, 1]; then 3 -> thread 1 (1), 2 -> thread 1 (4)...
    assert _owners([0, -1, 1, -1], [4, 3, 1, 2], 2, False) == [0, 1, 1, 0]
    assert _owners([-1, -1, -1], [1, 1, 1], 2, False) == [0, 1, 0]
    # a home beyond the thread count (threads were reduced) counts as none
    assert _owners([3, 0], [1, 1], 2, False) == [1, 0]


def test_without_rebalancing_every_home_is_kept() -> None:
    assert _owners([0, 0, 0, 0], [1, 1, 1, 1], 2, False) == [0, 0, 0, 0]


def test_rebalancing_moves_the_fewest_equal_experts() -> None:
    """Eight experts of equal work, six at home on thread 0: two move (the last ones), and
    the others keep their homes."""
    homes = [0, 0, 1, 0, 0, 1, 0, 0]
    assert _owners(homes, [7] * 8, 2) == [0, 0, 1, 0, 0, 1, 1, 1]


def test_rebalancing_moves_the_largest_expert_that_narrows_the_gap() -> None:
    # loads [10 + 6 + 1, 0]: the gap 17 admits 10 (gap |17 - 20| = 3), the largest below it
    assert _owners([0, 0, 0], [10, 6, 1], 2) == [1, 0, 0]


@settings(max_examples=200, deadline=None)
@given(st.data())
def test_the_assignment_is_as_balanced_as_one_move_at_a_time_allows(data: st.DataObject
                                                                   ) -> None:
    """Against a brute-force oracle: every owner is a thread; an expert keeps its home
    unless it moved; no single move from the most to the least loaded thread narrows the gap
    any more (the loop's stopping rule); and with two threads no assignment moving as few
    experts does better than half the largest work."""
    groups = data.draw(st.integers(1, 3))
    m = data.draw(st.integers(0, 7))
    homes = data.draw(st.lists(st.integers(-1, groups), min_size=m, max_size=m))
    work = data.draw(st.lists(st.integers(0, 50), min_size=m, max_size=m))
    owners = _owners(homes, work, groups)
    assert all(0 <= o < groups for o in owners)
    loads = _loads(owners, work, groups)
    hi, lo = int(np.argmax(loads)), int(np.argmin(loads))
    gap = loads[hi] - loads[lo]
    assert not any(o == hi and 0 < w < gap for o, w in zip(owners, work, strict=True))
    if groups == 2 and m:
        best = min(abs(_loads(list(a), work, 2)[0] - _loads(list(a), work, 2)[1])
                   for a in itertools.product(range(2), repeat=m))
        assert gap <= best + max(work)


@pytest.mark.usefixtures("batch_every_size")
def test_learning_does_not_depend_on_which_thread_takes_an_expert(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The same stream with each expert on its home thread and with every expert's thread
    drawn at random at each call: the same state, bit for bit."""
    jit.set_threads(2)
    real = jit.balanced_owners
    rng = np.random.default_rng(5)

    def shuffled(homes: np.ndarray, work: np.ndarray, groups: int, rebalance: bool
                 ) -> np.ndarray:
        real(homes, work, groups, rebalance)
        return np.asarray(rng.integers(0, groups, size=homes.shape[0]), dtype=np.int64)

    states = []
    for owners in (real, shuffled):
        monkeypatch.setattr(jit, "balanced_owners", owners)
        model = learn_stream(2)
        assert max(g.n for g in model.distinct_experts()) == 20
        states.append(model.state_dict())
    assert states[0].keys() == states[1].keys()
    for key in states[0]:
        np.testing.assert_array_equal(states[0][key], states[1][key], err_msg=key)


@pytest.mark.usefixtures("batch_every_size")
def test_each_expert_keeps_its_thread_from_step_to_step() -> None:
    """After a step every expert has a home (a thread) but the one opened by that step (not
    evaluated yet); copies inherit their source's; from one step to the next few experts
    change thread."""
    jit.set_threads(2)
    s = subtask_stream(200, seed=4)
    model = Roger(23, 9, RogerParams(beta=20), seed=3)
    moved = kept = 0
    for i, (x, y) in enumerate(zip(s.x, s.y, strict=True)):
        before = {id(g): g.home for g in model.distinct_experts()}
        model.learn_one(x, y)
        if i < 100:
            continue
        for g in model.distinct_experts():
            if before.get(id(g), -1) >= 0:
                kept += g.home == before[id(g)]
                moved += g.home != before[id(g)]
    homes = [g.home for g in model.distinct_experts()]
    assert homes.count(-1) <= 1 and all(h in (-1, 0, 1) for h in homes)
    assert kept > 10 * moved > 0
    copy = model.distinct_experts()[0].copy()
    assert copy.home == model.distinct_experts()[0].home
