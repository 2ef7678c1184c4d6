"""The experts of every particle, each held once, in integer slots (docs/performance.md,
pitfalls 13-15 of docs/learner-math.md §7).

A ROGER particle is one partition of the data into experts (paper Algorithm 1).  The
particles share most of their experts, so an expert version lives in one *slot* and a particle
is a run of slots in one flat array: particle ``p`` holds ``slots[starts[p]:starts[p + 1]]``,
with log weight ``log_weights[p]``.  Per slot the store keeps the expert (an object it only
copies and releases, :class:`Expert`), its id, its point count (the CRP's ``n_k``), how many
particles hold it, and its NIW gate (a row of :class:`.gates.GatePool`).

Copy-on-write: after resampling, a survivor that puts the point into an expert another
survivor keeps unchanged gets a copy in a new slot (:meth:`ExpertStore.writable`), made in a
buffer of the dropped experts' (:class:`.buffers.BufferPool`); survivors that choose the same
slot share one updated version.  :meth:`ExpertStore.advance` then replaces the particles by the
survivors and frees the slots none of them holds.  What each expert learns is the caller's:
the store takes arrays, slot indices and experts, not the paper's classes.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Generic, Protocol, Self, TypeVar

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.engine import jit as _jit
from roger_daemon.learner.engine.buffers import BufferPool, PendingCopy, copy_many
from roger_daemon.learner.engine.gates import GatePool

__all__ = ["Expert", "ExpertStore"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


class Expert(Protocol):
    """What the store needs of an expert: a copy into a pooled buffer, and its buffers back."""

    def copy(self, pool: BufferPool | None = None,
             pending: list[PendingCopy] | None = None) -> Self:
        """An independent copy, its buffer from ``pool`` (filled later with ``pending``)."""

    def release(self, pool: BufferPool) -> None:
        """Give the expert's buffers to ``pool`` (the expert is dropped)."""


E = TypeVar("E", bound=Expert)


class ExpertStore(Generic[E]):
    """Expert versions in slots, the particles as runs of slots, copy-on-write between them.

    ``new_expert()`` makes an empty expert; ``pool_limit`` bounds the kept buffers of each size
    (those of at most as many experts as there are particles).  Before anything is learned
    there is one particle without experts.
    """

    def __init__(self, gates: GatePool, new_expert: Callable[[], E], pool_limit: int) -> None:
        self.gates = gates
        self.new_expert = new_expert
        cap = gates.capacity
        self._experts: list[E | None] = [None] * cap
        self.ids = np.full(cap, -1, dtype=np.int64)  # expert id by slot (-1: free)
        self.counts = np.zeros(cap, dtype=np.int64)  # points of each version (CRP n_k)
        self.ref = np.zeros(cap, dtype=np.int64)  # particles holding each slot
        self._free: list[int] = list(range(cap - 1, -1, -1))  # pop() yields the lowest slot
        # dropped experts' slabs, reused by copy-on-write copies (not state)
        self.pool = BufferPool(limit=pool_limit)
        self._pending: list[PendingCopy] = []  # copies to make (:meth:`finish_copies`)
        self.next_id = 0
        # the particles, flat (one array for all, so a step's bookkeeping is one compiled
        # call each: :mod:`.jit_layout`)
        self.slots = np.zeros(0, dtype=np.int64)
        self.starts = np.zeros(2, dtype=np.int64)
        self.log_weights = np.zeros(1)

    # -- reading -----------------------------------------------------------------------------

    @property
    def capacity(self) -> int:
        """Slots allocated (doubled when full)."""
        return len(self._experts)

    @property
    def n_particles(self) -> int:
        """Particles carried."""
        return self.starts.size - 1

    def expert(self, slot: int) -> E:
        """The expert in ``slot`` (which must hold one)."""
        got = self._experts[slot]
        assert got is not None, f"slot {slot} holds no expert"
        return got

    def experts(self, slots: list[int]) -> list[E]:
        """The experts in ``slots``, in order."""
        return [self.expert(s) for s in slots]

    def live(self) -> IntArray:
        """The slots some particle holds, ascending."""
        return np.flatnonzero(self.ref > 0)

    def distinct(self) -> list[E]:
        """The distinct expert versions the particles hold, by slot."""
        return [e for e, r in zip(self._experts, self.ref.tolist(), strict=True)
                if r > 0 and e is not None]

    def particle(self, p: int) -> IntArray:
        """The slots of particle ``p``, in order (a copy)."""
        return self.slots[self.starts[p]: self.starts[p + 1]].copy()

    def map_particle(self) -> int:
        """The particle of highest weight (the first of equals)."""
        return int(self.log_weights.argmax())

    # -- a step's survivors (paper Algorithm 1, last lines) -----------------------------------

    def survivor_counts(self, parents: IntArray, chosen: IntArray) -> tuple[list[bool], IntArray]:
        """For survivors that each extend particle ``parents[r]`` by putting the point into
        slot ``chosen[r]`` (``-1``: a new expert): whether some survivor keeps each slot's old
        version (its copy-on-write flag, by slot), and the distinct chosen slots ascending
        (``-1`` first)."""
        contains, chose, distinct = _jit.survivor_counts(self.slots, self.starts, parents,
                                                         chosen, self.capacity)
        return (contains != chose).tolist(), distinct

    def open(self, x: FloatArray) -> tuple[int, E]:
        """A new expert for the point with input ``x``: its slot, and the expert, empty, for
        the caller to teach the point.  Its gate is the prior updated with ``x``, its id the
        next, its count 1."""
        slot = self._alloc()
        expert = self.new_expert()
        self._experts[slot] = expert
        self.gates.set_prior_updated(slot, x)
        self.ids[slot] = self.next_id
        self.next_id += 1
        self.counts[slot] = 1
        return slot, expert

    def writable(self, slot: int, shared: bool) -> tuple[int, E]:
        """The version of ``slot``'s expert that is to learn the point: itself (``shared``
        false: nobody keeps the old version), or a copy in a new slot with the same id and
        gate.  A copy's buffers are filled by :meth:`finish_copies`, several at once."""
        if not shared:
            return slot, self.expert(slot)
        target = self._alloc()
        expert = self.expert(slot).copy(self.pool, self._pending)
        self._experts[target] = expert
        self.gates.copy_slot(target, slot)
        self.ids[target] = self.ids[slot]
        return target, expert

    def finish_copies(self) -> None:
        """Fill the copies :meth:`writable` made (:func:`.buffers.copy_many`)."""
        copy_many(self._pending)
        self._pending = []

    def advance(self, parents: IntArray, chosen: IntArray, positions: IntArray,
                sources: IntArray, targets: IntArray, new_slot: int,
                log_weights: FloatArray) -> IntArray:
        """Replace the particles by the survivors: survivor ``r`` is particle ``parents[r]``
        with its chosen slot (at ``positions[r]``) replaced by that slot's updated version
        (``targets[i]`` for ``sources[i]``) or, for a new expert, ``new_slot`` appended; each
        updated version counts one point more than its source.  Frees the slots no survivor
        holds (their buffers go to the pool); returns each survivor's chosen expert id."""
        self.counts[targets] = self.counts[sources] + 1
        slots, starts, chosen_ids, ref, freed = _jit.survivor_particles(
            self.slots, self.starts, parents, chosen, positions, sources, targets, new_slot,
            self.ids, self.ref)
        for s in freed.tolist():
            dropped = self._experts[s]
            if dropped is not None:
                dropped.release(self.pool)  # its buffers serve later copies (.buffers)
            self._experts[s] = None
            self.ids[s] = -1
            self.counts[s] = 0
            self._free.append(s)
        self._free.sort(reverse=True)
        self.ref = ref
        self.slots, self.starts = slots, starts
        self.log_weights = log_weights
        out: IntArray = chosen_ids
        return out

    # -- state ---------------------------------------------------------------------------------

    def canonical(self) -> tuple[IntArray, IntArray]:
        """``(live, compact)``: the live slots by first appearance in the particles (not by
        slot number, so equal models give equal states), and each slot's index among them
        (``-1`` for the others)."""
        flat = self.slots
        _, first = np.unique(flat, return_index=True)
        live = flat[np.sort(first)]
        compact = np.full(self.capacity, -1, dtype=np.int64)
        compact[live] = np.arange(live.size)
        return live, compact

    def state(self) -> dict[str, np.ndarray]:
        """The store's arrays in the canonical order (:meth:`canonical`): ``gate_*`` (each
        field of :class:`.gates.GatePool`), ``expert_id``, ``expert_count``, and the particles
        (``particle_log_weights``, ``particle_offsets``, ``particle_experts``)."""
        live, compact = self.canonical()
        out = {f"gate_{name}": getattr(self.gates, name)[live].copy()
               for name in self.gates.FIELDS}
        out["expert_id"] = self.ids[live].copy()
        out["expert_count"] = self.counts[live].copy()
        out["particle_log_weights"] = self.log_weights.copy()
        out["particle_offsets"] = self.starts.copy()
        out["particle_experts"] = compact[self.slots]
        return out

    def load(self, experts: list[E], state: dict[str, np.ndarray], next_id: int) -> None:
        """Fill this fresh store with ``experts`` (in the canonical order) and the arrays of
        :meth:`state`."""
        u = len(experts)
        for _ in range(u):
            self._alloc()
        for s, expert in enumerate(experts):
            self._experts[s] = expert
        for name in self.gates.FIELDS:
            getattr(self.gates, name)[:u] = state[f"gate_{name}"]
        self.ids[:u] = state["expert_id"]
        self.counts[:u] = state["expert_count"]
        flat = np.asarray(state["particle_experts"], dtype=np.int64)
        self.slots = flat.copy()
        self.starts = np.asarray(state["particle_offsets"], dtype=np.int64).copy()
        self.log_weights = np.asarray(state["particle_log_weights"], dtype=np.float64).copy()
        self.ref = np.bincount(flat, minlength=self.capacity).astype(np.int64)
        self.next_id = int(next_id)

    def _alloc(self) -> int:
        """A free slot, the lowest; twice the slots when none is left."""
        if not self._free:
            old = self.capacity
            new = 2 * old
            self.gates.grow(new)
            self._experts.extend([None] * (new - old))
            self.ids = _grown(self.ids, new, -1)
            self.counts = _grown(self.counts, new, 0)
            self.ref = _grown(self.ref, new, 0)
            self._free = list(range(new - 1, old - 1, -1))
        return self._free.pop()


def _grown(arr: IntArray, size: int, fill: int) -> IntArray:
    """``arr`` in a buffer of ``size`` entries, the new ones ``fill``."""
    out = np.full(size, fill, dtype=np.int64)
    out[:arr.size] = arr
    return out
