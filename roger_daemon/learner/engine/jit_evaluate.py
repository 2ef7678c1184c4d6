"""Several experts at one input in one compiled call: a step's evaluation (paper Algorithm 1,
docs/learner-math.md §4) and a prediction's multimap (Algorithm 2, §6).

Both evaluate many small experts at one point: the AIBO experiment's ~25 experts of ~10 basis
vectors cost ~1.5 µs of compiled work each but ~7–10 µs each through
:meth:`.sogp.SparseOnlineGP.terms` (a call, slicing, a tuple).  :func:`evaluate_experts` runs
the same kernel, :func:`.jit_kernels.expert_terms`, for up to :data:`.jit.EVALUATION_WIDTH`
experts per call and finishes each expert's mean and latent variance as
:meth:`.sogp.SparseOnlineGP.terms` does, operation for operation (:func:`evaluate_expert`), so
the floats are its, bit for bit (tests/learner/test_jit_batch.py for a step's evaluation,
tests/learner/test_jit.py for a prediction's).  One thread: the experts are small; large
experts on several threads go to :func:`.jit_batch.terms_batch`, which runs
:func:`evaluate_expert` too.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.engine import jit_slab
from roger_daemon.learner.engine.jit_compile import compiled as _compiled
from roger_daemon.learner.engine.jit_kernels import expert_terms

__all__ = ["evaluate_expert", "evaluate_experts", "evaluate_slab", "slab_views"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


@_compiled(nogil=True)
def evaluate_expert(basis: FloatArray, cov: FloatArray, coef: FloatArray, prior: FloatArray,
                    n: int, alloc: int, x: FloatArray, gamma: float, k_star: float,
                    floor: float, prior_mean: bool, out: FloatArray, start: int,
                    mean_out: FloatArray) -> float:
    """One expert (``n >= 1`` basis vectors) at ``x``: its ``[k, C k, k^T C k, k^T A]``
    (:func:`.jit_kernels.expert_terms`) written at ``out[start:]``, its predictive mean into
    ``mean_out`` (``k^T A``, plus the prior mean ``prior`` when ``prior_mean``), and its latent
    variance ``max(k* + k^T C k, floor)`` returned (the sign of ``k^T C k``:
    docs/learner-math.md §2.4), as :meth:`.sogp.SparseOnlineGP.terms` makes them."""
    packed = expert_terms(basis, cov, coef, x, gamma, n, alloc)
    out[start: start + packed.shape[0]] = packed
    base = 2 * n + 1
    if prior_mean:
        for c in range(mean_out.shape[0]):
            mean_out[c] = packed[base + c] + prior[c]
    else:
        for c in range(mean_out.shape[0]):
            mean_out[c] = packed[base + c]
    latent: float = k_star + packed[2 * n]
    if floor > latent:  # Python's max(latent, floor), NaN included
        latent = floor
    return latent


_slab_offsets = _compiled(nogil=True)(jit_slab.slab_offsets)


@_compiled(nogil=True)
def slab_views(slab: FloatArray
               ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """An expert's ``(C, Q, B, A, m)`` as views of its slab, laid out as its header says
    (:mod:`.jit_slab`; the same views as :meth:`.sogp_steps.SOGPSteps._bind` takes)."""
    alloc, a_cols, d_x, d_y = int(slab[0]), int(slab[1]), int(slab[2]), int(slab[3])
    c, q, b, a, m, end = _slab_offsets(alloc, d_x, a_cols, d_y)
    size = alloc * (alloc + 1) // 2
    return (slab[c: c + size], slab[q: q + size],
            slab[b: b + alloc * d_x].reshape((alloc, d_x)),
            slab[a: a + alloc * a_cols].reshape((alloc, a_cols)), slab[m:end])


@_compiled(nogil=True)
def evaluate_slab(slab: FloatArray, n: int, x: FloatArray, gamma: float, k_star: float,
                  floor: float, prior_mean: bool, out: FloatArray, start: int,
                  mean_out: FloatArray) -> float:
    """:func:`evaluate_expert` of the expert whose buffers are ``slab``."""
    cov, _, basis, coef, prior = slab_views(slab)
    return evaluate_expert(basis, cov, coef, prior, n, basis.shape[0], x, gamma, k_star,
                           floor, prior_mean, out, start, mean_out)


@_compiled(nogil=True)
def evaluate_experts(slabs: tuple[FloatArray, ...], count: int, ns: IntArray, x: FloatArray,
                     gamma: float, k_star: float, floor: float, prior_mean: bool,
                     out: FloatArray, offsets: IntArray, means: FloatArray, latent: FloatArray
                     ) -> None:
    """:func:`evaluate_expert` of the first ``count`` experts, given by their slabs
    (:mod:`.jit_slab`): expert ``e``'s terms at ``out[offsets[e]:]``, its mean into
    ``means[e]``, its latent variance into ``latent[e]``."""
    for e in range(count):
        latent[e] = evaluate_slab(slabs[e], ns[e], x, gamma, k_star, floor, prior_mean, out,
                                  offsets[e], means[e])
