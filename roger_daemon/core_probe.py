"""How far apart the machine's first two CPUs are: a cache line bounced between them.

This project's shared virtual machines have spells in which the hypervisor runs the two vCPUs
on cores far apart (other dies or sockets): a cache line written by one CPU then takes the
other ~4 times as long to fetch, the learner's two threads slow by up to ~25 %, and the
single-threaded speed probe of :mod:`.machine` does not see it (docs/performance.md, *The
slow spells are the two cores far apart*). :func:`round_trip_ns` measures it: two threads
pinned to two CPUs hand one 8-byte counter back and forth (each waits for the other's value,
then writes its own), and the time of one round trip is the probe's reading.

The counter is read and written with atomic acquire and release operations compiled by numba
(an LLVM ``load atomic`` / ``store atomic``, a plain ``mov`` on x86-64), in functions that
release the GIL, so the two Python threads run at once.
"""

from __future__ import annotations

import os
import threading
import time
from typing import Any

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.engine.jit_target import pin

pin()  # before numba compiles anything: the learner's kernels keep their one target

from numba import njit, types  # noqa: E402  (after pin, as in .learner.jit_compile)
from numba.extending import intrinsic  # noqa: E402

__all__ = ["SPIN_LIMIT", "hand_over", "round_trip_ns"]

#: a waiting thread gives up after this many reads of the counter (seconds of spinning)
SPIN_LIMIT = 1 << 31
_START_TIMEOUT_S = 10.0  # the two threads must both be pinned and ready within this


@intrinsic
def _load_acquire(typingctx: Any, array: Any, index: Any) -> Any:
    """``array[index]`` read with acquire ordering (LLVM ``load atomic ... acquire``)."""
    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        data = context.make_array(signature.args[0])(context, builder, args[0]).data
        return builder.load_atomic(builder.gep(data, [args[1]]), "acquire", 8)

    return types.int64(array, index), codegen


@intrinsic
def _store_release(typingctx: Any, array: Any, index: Any, value: Any) -> Any:
    """``array[index] = value`` written with release ordering (LLVM ``store atomic``)."""
    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        data = context.make_array(signature.args[0])(context, builder, args[0]).data
        builder.store_atomic(args[2], builder.gep(data, [args[1]]), "release", 8)
        return context.get_dummy_value()

    return types.void(array, index, value), codegen


@njit(nogil=True)
def hand_over(counter: npt.NDArray[np.int64], trips: int, starts: bool,
              spin_limit: int = SPIN_LIMIT) -> int:
    """One side of ``trips`` round trips on ``counter[0]`` (which starts at 0): the starting
    side writes ``2 i + 1`` and waits for ``2 i + 2``, the other waits for ``2 i + 1`` and
    writes ``2 i + 2``. Returns the round trips made (fewer when a wait ran past
    ``spin_limit`` reads)."""
    for i in range(trips):
        wanted = 2 * i + 2 if starts else 2 * i + 1
        if starts:
            _store_release(counter, 0, 2 * i + 1)  # type: ignore[call-arg]
        spins = 0
        while _load_acquire(counter, 0) != wanted:  # type: ignore[call-arg]
            spins += 1
            if spins > spin_limit:
                return i
        if not starts:
            _store_release(counter, 0, 2 * i + 2)  # type: ignore[call-arg]
    return trips


def _one_run(cpus: tuple[int, int], trips: int) -> float | None:
    """ns per round trip of one run of two pinned threads, or ``None`` if it did not finish."""
    counter = np.zeros(16, dtype=np.int64)  # 128 bytes: the counter alone in its cache line
    ready = threading.Barrier(2, timeout=_START_TIMEOUT_S)
    elapsed: dict[bool, int] = {}
    made: dict[bool, int] = {}

    def side(cpu: int, starts: bool) -> None:
        try:
            os.sched_setaffinity(0, {cpu})  # this thread only (Linux: 0 is the calling thread)
            ready.wait()
        except (OSError, threading.BrokenBarrierError):
            ready.abort()
            return
        t0 = time.perf_counter_ns()
        made[starts] = hand_over(counter, trips, starts)
        elapsed[starts] = time.perf_counter_ns() - t0

    threads = [threading.Thread(target=side, args=(cpus[1], False), daemon=True),
               threading.Thread(target=side, args=(cpus[0], True), daemon=True)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    if made.get(True) != trips or made.get(False) != trips:
        return None
    return elapsed[True] / trips


def round_trip_ns(cpus: tuple[int, int] | None = None, trips: int = 20_000,
                  repeats: int = 5) -> float | None:
    """Best of ``repeats`` runs of ``trips`` round trips between two pinned threads, in ns
    per round trip; ``None`` where this process may use fewer than two CPUs, or cannot pin
    a thread, as on a system without ``sched_setaffinity`` (``cpus``: the two CPUs, by
    default the first two the calling thread may use).

    ~40–160 ns when the two CPUs are near (one die) on this project's AMD EPYC host,
    several hundred when they are far apart (docs/performance.md).
    """
    if not hasattr(os, "sched_setaffinity"):  # not Linux: threads cannot be pinned
        return None
    if cpus is None:
        usable = sorted(os.sched_getaffinity(0))
        if len(usable) < 2:
            return None
        cpus = (usable[0], usable[1])
    best: float | None = None
    for _ in range(repeats):
        ns = _one_run(cpus, trips)
        if ns is not None and (best is None or ns < best):
            best = ns
    return None if best is None else round(best, 1)
