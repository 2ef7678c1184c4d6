"""Garbage collection in idle moments, for the learner workers and the service loop.

CPython collects a generation whenever its allocation count crosses a threshold: in the
middle of whatever runs then. In an 8-robot daemon (AMD EPYC, 2026-11-27) a collection of the
young generation cost 0.15 ms of CPU on average and one of the middle generation 1.3 ms (up
to 3 ms), in every worker about once a second and in the loop as often: often inside a
prediction. A long-running process here calls :func:`hold_collections` once its start-up is
done, then :func:`collect_when_idle` at moments when nothing waits for it (a worker after
learning when no request waits, the loop at its quiet moments; docs/fleet.md, *Collections
in idle moments*). The same collections happen, by the interpreter's own rule, only at other
moments; the raised automatic thresholds are a backstop for a process that is never idle.
"""

from __future__ import annotations

import gc

__all__ = ["GC_BACKSTOP", "Thresholds", "collect_when_idle", "freeze_survivors",
           "hold_collections"]

Thresholds = tuple[int, int, int]

#: the automatic thresholds are raised this many times while collections are held
GC_BACKSTOP = 20


def hold_collections() -> Thresholds:
    """Collect once, freeze what survives (imports, compiled kernels, loaded models: never
    scanned again) and raise the automatic thresholds by :data:`GC_BACKSTOP`; return the
    interpreter's thresholds, which :func:`collect_when_idle` then applies itself. Once per
    process (:func:`freeze_survivors` after that)."""
    t0, t1, t2 = gc.get_threshold()
    gc.collect()
    gc.freeze()
    gc.set_threshold(t0 * GC_BACKSTOP, t1 * GC_BACKSTOP, t2 * GC_BACKSTOP)
    return t0, t1, t2


def freeze_survivors() -> Thresholds:
    """Collections already held (:func:`hold_collections`), more was loaded (another
    robot's model): collect once and freeze what survives; return the interpreter's
    thresholds (the raised ones divided back)."""
    gc.collect()
    gc.freeze()
    t0, t1, t2 = gc.get_threshold()
    return t0 // GC_BACKSTOP, t1 // GC_BACKSTOP, t2 // GC_BACKSTOP


def collect_when_idle(thresholds: Thresholds) -> int | None:
    """The interpreter's own rule, applied by the caller at an idle moment: the oldest
    generation whose count passed its threshold is collected (with the younger ones).
    Returns the generation collected, or ``None``."""
    counts = gc.get_count()
    for gen in (2, 1, 0):
        if counts[gen] > thresholds[gen]:
            gc.collect(gen)
            return gen
    return None
