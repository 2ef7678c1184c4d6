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
element of the buffer it takes, so which buffer it gets never changes a float.
"""

from __future__ import annotations

from collections import defaultdict

import numpy as np
import numpy.typing as npt

__all__ = ["BufferPool"]

FloatArray = npt.NDArray[np.float64]


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
        self._free: defaultdict[int, list[FloatArray]] = defaultdict(list)

    def give(self, buf: FloatArray) -> None:
        """Keep ``buf`` (1-D, float64, contiguous, owned by nobody else) for a later copy."""
        spare = self._free[buf.size]
        if len(spare) < self.limit:
            spare.append(buf)

    def take(self, size: int) -> FloatArray | None:
        """A kept buffer of ``size`` elements (its contents are stale), or ``None``."""
        spare = self._free.get(size)
        return spare.pop() if spare else None

    def copy_of(self, src: FloatArray,
                pending: list[tuple[FloatArray, FloatArray]] | None = None) -> FloatArray:
        """A copy of the 1-D ``src``, into a kept buffer when there is one of its size.

        With ``pending``, the buffer is returned unfilled and ``(src, buffer)`` appended: the
        caller copies every pending pair before the buffer is read (several copies at once:
        :func:`.sogp_batch.copy_many`)."""
        buf = self.take(src.size)
        if pending is not None:
            buf = np.empty_like(src) if buf is None else buf
            pending.append((src, buf))
            return buf
        if buf is None:
            return src.copy()
        np.copyto(buf, src)
        return buf

    def __len__(self) -> int:
        return sum(len(v) for v in self._free.values())
