"""The engine's store of experts (roger_daemon/learner/engine/store.py) on its own, with a
stand-in expert: copy-on-write only where another survivor keeps the old version, one updated
version for every survivor that chose a slot, the freed slots' buffers back in the pool, the
slots doubling when full, and a state that a fresh store reloads as it was."""

from __future__ import annotations

import numpy as np

from roger_daemon.learner.engine.buffers import BufferPool, PendingCopy
from roger_daemon.learner.engine.gates import GatePool
from roger_daemon.learner.engine.store import ExpertStore


class Counter:
    """A stand-in expert: a one-float buffer, copied through the pool like a real slab."""

    def __init__(self, value: float = 0.0) -> None:
        self.buf = np.array([value])
        self.home = -1

    def copy(self, pool: BufferPool | None = None,
             pending: list[PendingCopy] | None = None) -> Counter:
        out = Counter()
        out.buf = self.buf.copy() if pool is None else pool.copy_of(self.buf, pending)
        return out

    def release(self, pool: BufferPool) -> None:
        pool.give(self.buf)


def _store() -> ExpertStore[Counter]:
    return ExpertStore(GatePool(2, 0.0, 0.1, 1.0, 4.0, capacity=2), Counter, pool_limit=4)


def _step(store: ExpertStore[Counter], parents: list[int], chosen: list[int],
          x: np.ndarray) -> np.ndarray:
    """One step's survivors (particle ``parents[r]`` puts the point into slot ``chosen[r]``,
    ``-1`` a new expert), each chosen expert's buffer + 1, as ``instantiate`` does it."""
    par = np.array(parents, dtype=np.int64)
    cho = np.array(chosen, dtype=np.int64)
    pos = np.array([int(np.flatnonzero(store.particle(p) == s)[0]) if s >= 0 else 0
                    for p, s in zip(parents, chosen, strict=True)], dtype=np.int64)
    shared, distinct = store.survivor_counts(par, cho)
    new, sources, targets, updated = -1, [], [], []
    for s in distinct.tolist():
        if s < 0:
            new, expert = store.open(x)
            expert.buf[0] = 1.0
            continue
        t, expert = store.writable(s, shared[s])
        sources.append(s)
        targets.append(t)
        updated.append(expert)
    store.finish_copies()
    for expert in updated:
        expert.buf += 1.0
    return store.advance(par, cho, pos, np.array(sources, dtype=np.int64),
                         np.array(targets, dtype=np.int64), new,
                         np.full(len(parents), -np.log(len(parents))))


def test_copy_on_write_only_where_an_old_version_is_kept() -> None:
    store = _store()
    x = np.zeros(2)
    assert _step(store, [0], [-1], x).tolist() == [0]  # one particle, one new expert
    assert store.n_particles == 1 and store.counts.tolist()[:1] == [1]
    # two survivors of particle 0: one adds to expert 0, one opens expert 1
    assert _step(store, [0, 0], [0, -1], x).tolist() == [0, 1]
    p0, p1 = store.particle(0).tolist(), store.particle(1).tolist()
    assert store.ids[p0].tolist() == [0] and store.ids[p1].tolist() == [0, 1]
    assert p0 != p1[:1]  # expert 0 was copied: the second survivor kept the old version
    assert store.expert(p0[0]).buf[0] == 2.0 and store.expert(p1[0]).buf[0] == 1.0
    assert store.counts[p0[0]] == 2 and store.counts[p1[0]] == 1
    # both survivors choose the same slot: one updated version, in place, shared
    slot = p1[0]
    ids = _step(store, [1, 1], [slot, slot], x)
    assert ids.tolist() == [0, 0]
    assert store.particle(0).tolist() == store.particle(1).tolist() == p1
    assert store.expert(slot).buf[0] == 2.0 and store.counts[slot] == 2
    assert store.ref[slot] == 2 and len(store.distinct()) == 2


def test_freed_slots_give_their_buffers_to_the_pool_and_slots_double() -> None:
    store = _store()
    x = np.ones(2)
    _step(store, [0], [-1], x)
    for _ in range(3):  # each step opens an expert in one survivor, keeps the other
        _step(store, [0, 0], [-1, int(store.particle(0)[0])], x)
        _step(store, [0], [int(store.particle(0)[0])], x)
    assert store.capacity >= 4 and store.gates.capacity == store.capacity  # doubled
    assert store.n_particles == 1 and len(store.pool) > 0  # dropped versions' buffers
    assert np.count_nonzero(store.ref) == store.particle(0).size == len(store.distinct())
    assert (store.ids[store.ref == 0] == -1).all() and (store.counts[store.ref == 0] == 0).all()


def test_a_fresh_store_reloads_the_state_as_it_was() -> None:
    store = _store()
    x = np.array([0.5, -0.5])
    _step(store, [0], [-1], x)
    _step(store, [0, 0], [0, -1], x)
    live, compact = store.canonical()
    state = store.state()
    again = _store()
    again.load([Counter(float(store.expert(s).buf[0])) for s in live.tolist()], state,
               store.next_id)
    for name, value in again.state().items():
        np.testing.assert_array_equal(value, state[name], err_msg=name)
    assert again.next_id == store.next_id == 2
    assert [e.buf[0] for e in again.distinct()] == [store.expert(s).buf[0] for s in live]
    assert compact[live].tolist() == list(range(live.size))
