"""One buffer per expert, its *slab*: a header, the packed ``C`` and ``Q``, the basis vectors
``B``, the coefficients ``A`` and the prior mean ``m``, one after the other
(docs/performance.md, *One buffer per expert*).

The batched kernels (:mod:`.jit_batch`, :mod:`.jit_evaluate`) take the experts' slabs as one
tuple instead of one tuple per matrix: numba unboxes every array of a call's tuples (~57 ns
each on a 2-core AMD EPYC), and a step's two batched calls passed 4 x 32 + 4 x 16 of them.
The header makes a slab self-describing: its first floats are the expert's ``alloc`` (basis
vectors its buffers hold), ``a_cols`` (columns of ``A``), ``d_x`` and ``d_y``, integers held
exactly as floats, so a kernel needs no shape but the slab.
:func:`slab_offsets` is the layout's one owner: an expert (:meth:`.sogp_steps.SOGPSteps._bind`)
takes its views and writes the header with it, and the kernels slice with it
(:func:`.jit_evaluate.slab_views`).  Plain integer arithmetic, importable without numba; it
lives among the kernel modules so that numba's cache is tied to it (:mod:`.jit_compile`).
"""

from __future__ import annotations

__all__ = ["ALIGN", "HEADER", "slab_offsets"]

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
