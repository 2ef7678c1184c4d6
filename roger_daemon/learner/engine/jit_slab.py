"""One buffer per expert, its *slab*: a header, the packed ``C`` and ``Q``, the basis vectors
``B``, the coefficients ``A`` and the prior mean ``m``, one after the other
(docs/performance.md, *One buffer per expert*).

The batched kernels (:mod:`.jit_batch`, :mod:`.jit_evaluate`) take the experts' slabs as one
tuple instead of one tuple per matrix: numba unboxes every array of a call's tuples (~57 ns
each on a 2-core AMD EPYC), and a step's two batched calls passed 4 x 32 + 4 x 16 of them.
The header makes a slab self-describing: its first floats are the expert's ``alloc`` (basis
vectors its buffers hold), ``a_cols`` (columns of ``A``), ``d_x`` and ``d_y``, integers held
exactly as floats, so a kernel needs no shape but the slab.
:func:`slab_offsets` is the layout's one owner: :func:`bind` writes the header and takes an
expert's views with it, and the kernels slice with it (:func:`.jit_evaluate.slab_views`).
Importable without numba; it lives among the kernel modules so that numba's cache is tied to
it (:mod:`.jit_compile`).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import numpy.typing as npt

__all__ = ["ALIGN", "HEADER", "bind", "new_slab", "output_weights", "slab_offsets"]

FloatArray = npt.NDArray[np.float64]

#: each part starts a multiple of this many floats (64 bytes) after the slab's start, as the
#: separate buffers each started on their own allocation before
ALIGN = 8

#: floats before ``C``: ``alloc``, ``a_cols``, ``d_x``, ``d_y``, then padding to :data:`ALIGN`
HEADER = ALIGN


def slab_offsets(alloc: int, d_x: int, a_cols: int, d_y: int
                 ) -> tuple[int, int, int, int, int, int]:
    """Where ``C``, ``Q``, ``B``, ``A`` and ``m`` start in the slab of an expert with buffers
    for ``alloc`` basis vectors, and the slab's length.  ``C`` and ``Q`` hold ``alloc (alloc +
    1) / 2`` floats each (:func:`.packed.packed_size`), ``B`` ``alloc x d_x``, ``A`` ``alloc x
    a_cols``, ``m`` ``d_y``; the header (:data:`HEADER`) comes first.

    >>> slab_offsets(3, 2, 1, 1)  # C at 8 (6 floats), Q at 16, B at 24, A at 32, m at 40
    (8, 16, 24, 32, 40, 41)
    """
    packed = -(-(alloc * (alloc + 1) // 2) // ALIGN) * ALIGN
    q = HEADER + packed
    b = q + packed
    a = b + -(-(alloc * d_x) // ALIGN) * ALIGN
    m = a + -(-(alloc * a_cols) // ALIGN) * ALIGN
    return HEADER, q, b, a, m, m + d_y


def new_slab(alloc: int, d_x: int, a_cols: int, d_y: int) -> FloatArray:
    """A zeroed slab for ``alloc`` basis vectors (:func:`slab_offsets`), its header written."""
    slab = np.zeros(slab_offsets(alloc, d_x, a_cols, d_y)[5])
    slab[:4] = alloc, a_cols, d_x, d_y
    return slab


def bind(slab: FloatArray, alloc: int, d_x: int, a_cols: int, d_y: int
         ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """``slab``'s header written for ``alloc`` basis vectors and its parts as views ``(C, Q, B,
    A, m)``: the packed ``C`` and ``Q``, ``B`` (alloc, d_x), ``A`` (alloc, a_cols) and ``m``
    (d_y,), the same views as :func:`.jit_evaluate.slab_views` takes in the kernels."""
    c, q, b, a, m, end = slab_offsets(alloc, d_x, a_cols, d_y)
    size = alloc * (alloc + 1) // 2
    slab[:4] = alloc, a_cols, d_x, d_y
    return (slab[c: c + size], slab[q: q + size], slab[b: b + alloc * d_x].reshape(alloc, d_x),
            slab[a: a + alloc * a_cols].reshape(alloc, a_cols), slab[m:end])


@lru_cache(maxsize=8)
def output_weights(a_cols: int, d_y: int) -> FloatArray:
    """1 for the output columns of ``A``, 0 for a prior mean's ``a1`` column: the deletion
    scores count the outputs only (read-only)."""
    cw = np.ones(a_cols)
    cw[d_y:] = 0.0
    cw.setflags(write=False)
    return cw
