"""The particles' flat layout kernels (roger_daemon/learner/engine/jit_layout.py) against the
list-of-arrays code they replaced (each particle its own array, numpy per particle), as oracles."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from roger_daemon.learner.engine import jit_layout

CAP = 12


@st.composite
def particle_sets(draw: st.DrawFn) -> list[np.ndarray]:
    """1-6 particles, each 0-5 distinct slots below CAP (as a model's particles are)."""
    n = draw(st.integers(1, 6))
    return [np.array(draw(st.lists(st.integers(0, CAP - 1), max_size=5, unique=True)),
                     dtype=np.int64) for _ in range(n)]


def _flat(parts: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    sizes = [a.size for a in parts]
    return (np.concatenate(parts).astype(np.int64),
            np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64))


def _survivors(data: st.DataObject, parts: list[np.ndarray]
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distinct putatives (parent, position; position == size: a new expert)."""
    choices = [(i, pos) for i, a in enumerate(parts) for pos in range(a.size + 1)]
    picked = data.draw(st.lists(st.sampled_from(choices), min_size=1, max_size=len(choices),
                                unique=True))
    parent = np.array([i for i, _ in picked], dtype=np.int64)
    pos = np.array([p for _, p in picked], dtype=np.int64)
    slot = np.array([parts[i][p] if p < parts[i].size else -1 for i, p in picked],
                    dtype=np.int64)
    return parent, slot, pos


@settings(max_examples=200, deadline=None)
@given(parts=particle_sets(), data=st.data())
def test_putative_layout_is_the_per_particle_concatenation(parts: list[np.ndarray],
                                                           data: st.DataObject) -> None:
    floats = st.floats(-50.0, 50.0, allow_nan=False)
    logw = np.array(data.draw(st.lists(floats, min_size=len(parts), max_size=len(parts))))
    slot_term = np.array(data.draw(st.lists(floats, min_size=CAP, max_size=CAP)))
    new_term = data.draw(floats)
    slots, starts = _flat(parts)
    flat_slots, flat_part, offsets, base = jit_layout.putative_layout(
        slots, starts, logw, slot_term, new_term)
    # the numpy code the kernel replaced (roger_step.putatives before the flat layout)
    sizes = np.array([a.size + 1 for a in parts])
    want_slots = np.concatenate([a for s in parts for a in (s, np.array([-1]))])
    want_part = np.repeat(np.arange(len(parts)), sizes)
    is_new = want_slots < 0
    want_base = logw[want_part]
    want_base[is_new] += new_term
    want_base[~is_new] += slot_term[want_slots[~is_new]]
    np.testing.assert_array_equal(flat_slots, want_slots)
    np.testing.assert_array_equal(flat_part, want_part)
    np.testing.assert_array_equal(offsets, np.cumsum(sizes) - sizes)
    assert base.tobytes() == want_base.tobytes()  # the same additions, bit for bit


@settings(max_examples=200, deadline=None)
@given(parts=particle_sets(), data=st.data())
def test_survivor_counts_and_particles_match_the_per_particle_code(parts: list[np.ndarray],
                                                                   data: st.DataObject) -> None:
    parent, slot, pos = _survivors(data, parts)
    slots, starts = _flat(parts)
    contains, chose, chosen = jit_layout.survivor_counts(slots, starts, parent, slot, CAP)
    np.testing.assert_array_equal(
        contains, np.bincount(np.concatenate([parts[i] for i in parent.tolist()]),
                              minlength=CAP))
    np.testing.assert_array_equal(chose, np.bincount(slot[slot >= 0], minlength=CAP))
    np.testing.assert_array_equal(chosen, np.unique(slot))
    # each chosen slot's updated version: in place or a fresh slot; a new expert: a fresh one
    cap = 2 * CAP
    target = np.full(cap, -1, dtype=np.int64)
    fresh = iter(range(CAP, cap))
    for s in np.unique(slot[slot >= 0]).tolist():
        target[s] = s if data.draw(st.booleans()) else next(fresh)
    new_target = next(fresh)
    ids = np.array(data.draw(st.lists(st.integers(0, 99), min_size=cap, max_size=cap)),
                   dtype=np.int64)
    sources = np.flatnonzero(target >= 0)
    old_ref = np.array(data.draw(st.lists(st.integers(0, 3), min_size=cap, max_size=cap)),
                       dtype=np.int64)
    new_slots, new_starts, chosen_ids, ref, freed = jit_layout.survivor_particles(
        slots, starts, parent, slot, pos, sources, target[sources], new_target, ids, old_ref)
    want = []
    for i, s, p in zip(parent.tolist(), slot.tolist(), pos.tolist(), strict=True):
        arr = parts[i].copy()
        if s < 0:
            arr = np.append(arr, new_target)
        else:
            arr[p] = target[s]
        want.append(arr)
    got = [new_slots[new_starts[r]: new_starts[r + 1]] for r in range(parent.size)]
    assert [a.tolist() for a in got] == [a.tolist() for a in want]
    np.testing.assert_array_equal(
        chosen_ids, [ids[new_target if s < 0 else target[s]] for s in slot.tolist()])
    np.testing.assert_array_equal(ref, np.bincount(np.concatenate(want), minlength=cap))
    np.testing.assert_array_equal(freed, np.flatnonzero((old_ref > 0) & (ref == 0)))
