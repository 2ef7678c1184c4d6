"""The threads of the learner's batched kernels (:mod:`.jit_batch`; docs/performance.md,
*Both cores in one step*): how many, applied per Python thread, and when a call is worth them.

The results never depend on the count: each expert's floats are computed by one thread, in
the same order.  numba is imported only when a count is set or first used.
"""

from __future__ import annotations

import threading

__all__ = ["BATCH_LOCK", "BATCH_MIN_ENTRIES", "batch_worth", "check_threading_layer",
           "set_threads", "threads", "use_threads"]

#: below this many packed matrix entries per call (~2 full experts at the paper's beta = 300)
#: the experts go one at a time: a parallel call's start-up then costs more than splitting the
#: work saves (the AIBO stream's ~15-basis-vector experts: docs/performance.md)
BATCH_MIN_ENTRIES = 100_000

#: held while a batched kernel runs: numba's ``workqueue`` threading layer (used where neither
#: TBB nor OpenMP is available) must not be entered by two threads at once
BATCH_LOCK = threading.Lock()

_threads: int | None = None  # set_threads(): None until set or first used
_threads_default = True  # set_threads(None) (or never called)
_workqueue = False  # check_threading_layer found numba's threading layer to be workqueue
_applied = threading.local()  # .count: what numba.set_num_threads was given in this thread


def set_threads(count: int | None) -> None:
    """Threads of the batched kernels: ``count`` (capped at numba's ``NUMBA_NUM_THREADS``,
    every core unless that is set), or ``None`` for the default: every core, but one once
    :func:`check_threading_layer` finds numba on its ``workqueue`` threading layer (no TBB, no
    OpenMP: its threads sleep between calls and wake slower than the kernels run).  The
    results do not depend on it (docs/performance.md, *Both cores in one step*)."""
    global _threads, _threads_default
    if count is not None and count < 1:
        raise ValueError(f"threads must be an integer >= 1 or None, got {count!r}")
    import numba

    most = int(numba.config.NUMBA_NUM_THREADS)  # type: ignore[attr-defined]
    _threads_default = count is None
    _threads = (1 if _workqueue else most) if count is None else min(int(count), most)
    numba.set_num_threads(_threads)
    _applied.count = _threads


def threads() -> int:
    """The batched kernels' thread count (:func:`set_threads`; the default until set)."""
    if _threads is None:
        set_threads(None)
    assert _threads is not None
    return _threads


def use_threads() -> int:
    """Apply :func:`threads` to the calling thread (numba's count is per thread) and return
    it: called before each learner step's batched kernels."""
    count = threads()
    if getattr(_applied, "count", None) != count:
        import numba

        numba.set_num_threads(count)
        _applied.count = count
    return count


def batch_worth(entries: int) -> bool:
    """Whether experts whose packed matrices hold ``entries`` entries in all should go to a
    batched kernel (several threads and enough work: :data:`BATCH_MIN_ENTRIES`); else each
    expert's kernels are called one at a time, the same floats."""
    return entries >= BATCH_MIN_ENTRIES and use_threads() > 1


def check_threading_layer() -> None:
    """After the first parallel call (:func:`.jit.warm_up`): on ``workqueue`` the default is
    one thread."""
    global _workqueue
    import numba

    try:
        _workqueue = numba.threading_layer() == "workqueue"  # type: ignore[attr-defined]
    except ValueError:  # no parallel kernel has run in this process yet
        return
    if _workqueue and _threads_default:
        set_threads(None)
