"""The constants the learner's kernels are compiled with, and :func:`padded`, which builds the
batched kernels' tuples of experts' slabs (:mod:`.jit_batch`, :mod:`.jit_slab`).

Plain Python, importable without numba: the kernel modules import their constants from here
(numba compiles them in), and :mod:`.jit` hands them on.  Its name puts it among the modules
whose sources fingerprint numba's cache (:mod:`.jit_compile`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy.typing as npt

__all__ = ["ADDED", "DRIFTED", "EVALUATION_WIDTH", "FUSED", "KEPT", "NEEDS_ROOM", "PROJECTED",
           "SMALL", "WIDTH", "padded"]

#: up to this many basis vectors ``Q`` is re-inverted by the compiled Cholesky
#: (:func:`.jit_kernels.cholesky_inverse`); above, by LAPACK, which is faster there (2026-11-28,
#: 2-core AMD EPYC: 0.38 against 0.39 ms at 128, 0.81 against 0.71 ms at 200, 2.8 against 1.2
#: ms at 300, docs/performance.md, *A faster compiled re-inversion*).  (Expert evaluation and
#: ``Q k`` are compiled at every size since issue 11's second pass.)
SMALL = 128

#: experts per call of a batched kernel (:mod:`.jit_batch`): their slabs come as a tuple of
#: exactly this many arrays, so each kernel has one compiled signature; at the paper's
#: parameters a step's ~10 updates make one call
WIDTH = 16

#: experts per call of the evaluation's kernels (:func:`.jit_batch.terms_batch`,
#: :func:`.jit_evaluate.evaluate_experts`): a step's ~20 distinct experts at the paper's
#: parameters in one call, so one parallel region.  Each region ends when every thread has
#: finished, and in this project's hosts' slow spells a region costs ~50 µs more than its
#: work (docs/performance.md, *One parallel region for the evaluation*)
EVALUATION_WIDTH = 32

#: :func:`.jit_batch.learn_batch`'s outcome for an expert: the fused step done; not novel
#: (the caller makes the projection update); ``Q`` drifted (the caller re-inverts it first)
FUSED, KEPT, DRIFTED = 0, 1, 2

#: :func:`.jit_small.growth_step`'s outcome for an expert with room for another basis
#: vector: the point added as a basis vector (step 4b); its projection update made (not novel,
#: step 4a); novel but the buffers are full (nothing changed: the caller grows them first).
#: (:data:`DRIFTED`: ``Q`` must be re-inverted first; nothing changed.)
ADDED, PROJECTED, NEEDS_ROOM = 3, 4, 5


def padded(arrays: Sequence[npt.NDArray[Any]], start: int, width: int = WIDTH
           ) -> tuple[npt.NDArray[Any], ...]:
    """``arrays[start:start + width]`` as a tuple of exactly ``width`` arrays (:data:`WIDTH`
    or :data:`EVALUATION_WIDTH`), the last one repeated (a batched kernel reads only its
    first ``count``)."""
    chunk = tuple(arrays[start: start + width])
    return chunk + (chunk[-1],) * (width - len(chunk))
