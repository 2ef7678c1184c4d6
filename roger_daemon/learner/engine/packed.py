"""Packed symmetric storage of an expert's ``C`` and ``Q`` (docs/performance.md, issue 11).

At the paper's capacity (beta = 300) a learner step is bound by the bytes it streams over the
experts' ``C`` and ``Q``.  Both are symmetric, so only the upper triangle is stored, row by row
in one flat buffer: row ``i`` holds ``S[i, i:alloc]`` and starts at
``offset(i) = i * alloc - i * (i - 1) / 2``, for a buffer sized for ``alloc`` basis vectors.
The live block is the leading ``n x n`` (``n <= alloc``): row ``i``'s live entries are the
first ``n - i`` of its row; the rest is padding, never read.  A stored matrix is exactly
symmetric by construction.

This module converts between that layout and full matrices (state dicts, tests, the rare
steps that permute rows); the compiled kernels (:mod:`.jit_kernels`) read and update the
packed buffers directly.  No I/O.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import numpy.typing as npt

__all__ = ["diagonal", "pack", "pack_into", "packed_size", "row_offsets", "unpack"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


def packed_size(alloc: int) -> int:
    """Length of the flat buffer of an ``alloc x alloc`` symmetric matrix."""
    return alloc * (alloc + 1) // 2


@lru_cache(maxsize=32)
def row_offsets(alloc: int) -> IntArray:
    """``offset(i)`` for ``i < alloc``: where row ``i`` starts (read-only)."""
    i = np.arange(alloc, dtype=np.int64)
    out = i * alloc - i * (i - 1) // 2
    out.setflags(write=False)
    return out


@lru_cache(maxsize=64)
def _positions(alloc: int, n: int) -> tuple[IntArray, IntArray, IntArray]:
    """``(rows, cols, flat)`` of the upper triangle of the live ``n x n`` block."""
    rows, cols = np.triu_indices(n)
    flat = row_offsets(alloc)[rows] + (cols - rows)
    for a in (rows, cols, flat):
        a.setflags(write=False)
    return rows, cols, flat


def diagonal(buf: FloatArray, alloc: int, n: int) -> FloatArray:
    """The diagonal of the live block (a copy)."""
    return buf[row_offsets(alloc)[:n]]


def pack_into(buf: FloatArray, alloc: int, full: FloatArray, n: int) -> None:
    """Store the upper triangle of ``full[:n, :n]`` as the live block of ``buf``."""
    rows, cols, flat = _positions(alloc, n)
    buf[flat] = full[rows, cols]


def pack(full: FloatArray, alloc: int) -> FloatArray:
    """A new buffer for ``alloc`` basis vectors holding the symmetric ``full`` (n x n)."""
    buf = np.zeros(packed_size(alloc))
    pack_into(buf, alloc, full, full.shape[0])
    return buf


def unpack(buf: FloatArray, alloc: int, n: int) -> FloatArray:
    """The live block as a full symmetric ``n x n`` matrix (a copy)."""
    rows, cols, flat = _positions(alloc, n)
    full = np.empty((n, n))
    vals = buf[flat]
    full[rows, cols] = vals
    full[cols, rows] = vals
    return full

