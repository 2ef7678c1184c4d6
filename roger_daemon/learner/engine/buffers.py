"""Reused matrix buffers for copy-on-write copies of experts (docs/performance.md).

A ROGER step copies an expert when survivors that keep the old version share it with one that
learns the new point (paper Algorithm 1; :func:`.roger_step.instantiate`), and frees the
versions no survivor holds. At beta = 300 each copy allocates the expert's slab
(:mod:`.jit_slab`: two packed matrices of 361 KB, ``C`` and ``Q``, and the small ``B``, ``A``
and prior mean; ``K_B`` is not kept). Where blocks that large are served by ``mmap`` (the
daemon fixes glibc's threshold at 128 KiB to keep its resident size flat,
:mod:`roger_daemon.daemon.memory`) every such allocation is ~90 page faults and every free an
``munmap``: measured at the paper's parameters (with ``K_B`` still kept), 84 faults per step
and an update p99 of 5.0 ms instead of 2.9 ms. :class:`BufferPool` keeps the freed experts'
slabs and hands them to the next copies, so the pages stay mapped. A copy writes every
element of the buffer it takes, so which buffer it gets never changes a float. Each kept slab
remembers the thread whose cache last held it (its expert's home, :mod:`.jit_batch`), and a
copy made on that thread takes one of those first: on a host that places the two cores far
apart, writing a slab the other core last held costs more (a step's copies 18.0 against 11.3
µs there, docs/performance.md, *The slow spells are the two cores far apart*).
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.engine import jit as _jit

__all__ = ["BufferPool", "PendingCopy", "copy_many"]

FloatArray = npt.NDArray[np.float64]
#: a copy deferred by :meth:`BufferPool.copy_of`: its source, its buffer and the thread that
#: is to make it (the source's home, :mod:`.jit_batch`)
PendingCopy = tuple[FloatArray, FloatArray, int]


class BufferPool:
    """Freed float64 buffers by size, at most ``limit`` of each size (the rest are dropped).

    >>> pool = BufferPool(limit=2)
    >>> pool.give(np.zeros(6))
    >>> pool.take(6).shape, pool.take(6)
    ((6,), None)
    """

    def __init__(self, limit: int) -> None:
        if limit < 0:
            raise ValueError(f"limit must be an integer >= 0, got {limit!r}")
        self.limit = limit
        self._free: defaultdict[int, list[tuple[int, FloatArray]]] = defaultdict(list)

    def give(self, buf: FloatArray, home: int = -1) -> None:
        """Keep ``buf`` (1-D, float64, contiguous, owned by nobody else) for a later copy;
        ``home``: the thread whose cache last held it (:mod:`.jit_batch`)."""
        spare = self._free[buf.size]
        if len(spare) < self.limit:
            spare.append((home, buf))

    def take(self, size: int, home: int = -1) -> FloatArray | None:
        """A kept buffer of ``size`` elements (its contents are stale), or ``None``: the
        last kept of those last held by ``home``, else the last kept.

        >>> pool = BufferPool(limit=3)
        >>> a, b, c = np.zeros(2), np.zeros(2), np.zeros(2)
        >>> pool.give(a, home=0); pool.give(b, home=1); pool.give(c, home=1)
        >>> pool.take(2, home=0) is a, pool.take(2, home=0) is c, pool.take(2, home=1) is b
        (True, True, True)
        """
        spare = self._free.get(size)
        if not spare:
            return None
        at = len(spare) - 1
        for i in range(len(spare) - 1, -1, -1):
            if spare[i][0] == home:
                at = i
                break
        return spare.pop(at)[1]

    def copy_of(self, src: FloatArray,
                pending: list[PendingCopy] | None = None,
                home: int = -1) -> FloatArray:
        """A copy of the 1-D ``src``, into a kept buffer when there is one of its size.

        ``home``: the thread that will make the copy (:meth:`take`).  With ``pending``, the
        buffer is returned unfilled and ``(src, buffer, home)`` appended: the
        caller makes every pending copy before the buffer is read (several copies at once:
        :func:`copy_many`)."""
        buf = self.take(src.size, home)
        if pending is not None:
            buf = np.empty_like(src) if buf is None else buf
            pending.append((src, buf, home))
            return buf
        if buf is None:
            return src.copy()
        np.copyto(buf, src)
        return buf

    def __len__(self) -> int:
        return sum(len(v) for v in self._free.values())


def copy_many(pending: Sequence[PendingCopy]) -> None:
    """``np.copyto(dst, src)`` for each pair (a step's copy-on-write copies,
    :meth:`BufferPool.copy_of` with ``pending``): several per compiled call
    (:func:`.jit_batch.copy_batch`) when :func:`.jit.batch_worth` says so, each by the thread
    it names (its source's home)."""
    if not _jit.batch_worth(sum(src.size for src, _, _ in pending)):
        for src, dst, _ in pending:
            np.copyto(dst, src)
        return
    srcs = [src for src, _, _ in pending]
    dsts = [dst for _, dst, _ in pending]
    groups = _jit.threads()
    owners = _jit.balanced_owners(
        np.array([home for _, _, home in pending], dtype=np.int64),
        np.array([src.size for src in srcs], dtype=np.int64), groups, False)
    with _jit.BATCH_LOCK:
        for lo in range(0, len(pending), _jit.WIDTH):
            hi = min(lo + _jit.WIDTH, len(pending))
            _jit.copy_batch(_jit.padded(srcs, lo), _jit.padded(dsts, lo), hi - lo,
                            owners[lo:hi], groups)
