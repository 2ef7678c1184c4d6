"""Compiled kernels of the particles' flat layout (numba): one call where a step's bookkeeping
walked the particles one at a time.

A :class:`~.roger.Roger` model keeps its particles flat: particle ``p`` holds the expert
slots ``slots[starts[p]:starts[p + 1]]``.  Per step (paper Algorithm 1, docs/learner-math.md
§4):

* :func:`putative_layout`: every putative (each particle's experts, then one new empty
  expert), the particle it extends, where each particle's putatives start, and its log weight
  before the GP factor (particle weight + CRP + gate, one addition each);
* :func:`survivor_counts`: after resampling, how many survivors contain each slot and how
  many chose it (copy-on-write, :func:`.roger_step.instantiate`), and the chosen slots in
  ascending order (``-1``, a new expert, first);
* :func:`survivor_particles`: the surviving particles, the chosen expert of each survivor
  replaced by its updated version, their expert ids, the slots' reference counts and the
  slots no survivor holds any more.

Integers only, but for :func:`putative_layout`'s additions, which are the very IEEE additions
the numpy code made (tests/learner/test_jit_layout.py, against the per-particle numpy code
they replaced).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.engine.jit_compile import compiled

__all__ = ["putative_layout", "survivor_counts", "survivor_particles"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


@compiled(nogil=True)
def putative_layout(slots: IntArray, starts: IntArray, logw: FloatArray, slot_term: FloatArray,
                    new_term: float) -> tuple[IntArray, IntArray, IntArray, FloatArray]:
    """``(flat_slots, flat_part, offsets, base)`` of the putatives: particle ``p``'s experts in
    order then ``-1`` (a new expert), from ``offsets[p]`` on; ``base[j] = logw[p] +
    slot_term[s]`` for an expert in slot ``s``, ``logw[p] + new_term`` for the new one."""
    n_part = starts.size - 1
    m = slots.size + n_part
    flat_slots = np.empty(m, dtype=np.int64)
    flat_part = np.empty(m, dtype=np.int64)
    offsets = np.empty(n_part, dtype=np.int64)
    base = np.empty(m)
    j = 0
    for p in range(n_part):
        offsets[p] = j
        w = logw[p]
        for a in range(starts[p], starts[p + 1]):
            s = slots[a]
            flat_slots[j] = s
            flat_part[j] = p
            base[j] = w + slot_term[s]
            j += 1
        flat_slots[j] = -1
        flat_part[j] = p
        base[j] = w + new_term
        j += 1
    return flat_slots, flat_part, offsets, base


@compiled(nogil=True)
def survivor_counts(slots: IntArray, starts: IntArray, surv_parent: IntArray,
                    surv_slot: IntArray, cap: int) -> tuple[IntArray, IntArray, IntArray]:
    """``(contains, chose, chosen)``: over the survivors (each the putative of parent particle
    ``surv_parent[r]`` that chose slot ``surv_slot[r]``, ``-1``: a new expert), how many
    contain each of the ``cap`` slots and how many chose it; ``chosen``, the distinct chosen
    slots ascending (``np.unique(surv_slot)``)."""
    contains = np.zeros(cap, dtype=np.int64)
    chose = np.zeros(cap, dtype=np.int64)
    opened = False
    for r in range(surv_parent.size):
        i = surv_parent[r]
        for a in range(starts[i], starts[i + 1]):
            contains[slots[a]] += 1
        s = surv_slot[r]
        if s < 0:
            opened = True
        else:
            chose[s] += 1
    n_chosen = 1 if opened else 0
    for s in range(cap):
        if chose[s] > 0:
            n_chosen += 1
    chosen = np.empty(n_chosen, dtype=np.int64)
    j = 0
    if opened:
        chosen[0] = -1
        j = 1
    for s in range(cap):
        if chose[s] > 0:
            chosen[j] = s
            j += 1
    return contains, chose, chosen


@compiled(nogil=True)
def survivor_particles(slots: IntArray, starts: IntArray, surv_parent: IntArray,
                       surv_slot: IntArray, surv_pos: IntArray, sources: IntArray,
                       updated: IntArray, new_target: int, ids: IntArray, old_ref: IntArray
                       ) -> tuple[IntArray, IntArray, IntArray, IntArray, IntArray]:
    """``(new_slots, new_starts, chosen_ids, ref, freed)``: survivor ``r`` is its parent
    particle with its choice applied: the slot ``s`` at position ``surv_pos[r]`` replaced by
    its updated version (``updated[i]`` where ``sources[i] == s``), or ``new_target`` appended
    for a new expert; ``chosen_ids[r]`` is that expert's id (``ids``), ``ref`` counts each
    slot's holders (as many entries as ``ids``) and ``freed`` lists, ascending, the slots held
    before (``old_ref > 0``) that no survivor holds."""
    target = np.full(ids.size, -1, dtype=np.int64)
    for i in range(sources.size):
        target[sources[i]] = updated[i]
    k = surv_parent.size
    total = 0
    for r in range(k):
        i = surv_parent[r]
        total += starts[i + 1] - starts[i] + (1 if surv_slot[r] < 0 else 0)
    new_slots = np.empty(total, dtype=np.int64)
    new_starts = np.empty(k + 1, dtype=np.int64)
    chosen_ids = np.empty(k, dtype=np.int64)
    j = 0
    for r in range(k):
        i = surv_parent[r]
        new_starts[r] = j
        for a in range(starts[i], starts[i + 1]):
            new_slots[j] = slots[a]
            j += 1
        s = surv_slot[r]
        if s < 0:
            t = new_target
            new_slots[j] = t
            j += 1
        else:
            t = target[s]
            new_slots[new_starts[r] + surv_pos[r]] = t
        chosen_ids[r] = ids[t]
    new_starts[k] = j
    ref = np.zeros(ids.size, dtype=np.int64)
    for a in range(j):
        ref[new_slots[a]] += 1
    freed = np.empty(old_ref.size, dtype=np.int64)
    n_freed = 0
    for s in range(old_ref.size):
        if old_ref[s] > 0 and ref[s] == 0:
            freed[n_freed] = s
            n_freed += 1
    return new_slots, new_starts, chosen_ids, ref, freed[:n_freed]
