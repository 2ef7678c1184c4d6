"""Several experts' kernels in one compiled call, spread over the cores (numba ``prange``).

A learner step evaluates every distinct expert on the new point and then updates each chosen
one (paper Algorithm 1; docs/learner-math.md §4).  The experts are independent, so these
kernels run the per-expert bodies of :mod:`.jit_kernels` and :mod:`.jit_fused` for up to
:data:`.jit.WIDTH` experts per call, one expert per iteration of a parallel loop: each expert's
floats are computed by one thread, in the same order whatever the number of threads, so the
results do not depend on it (tested; docs/performance.md, *Both cores in one step*).

The experts' buffers come as tuples of exactly :data:`.jit.WIDTH` arrays (:func:`.jit.padded`),
so each kernel has one compiled signature whatever the number of experts; only the first
``count`` entries are read.  The number of threads is set by :func:`.jit.set_threads`.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from numba import prange

from roger_daemon.learner.jit import DRIFTED, FUSED, KEPT
from roger_daemon.learner.jit_compile import compiled as _compiled
from roger_daemon.learner.jit_fused import fused_step
from roger_daemon.learner.jit_kernels import expert_terms, novelty_test, projection

__all__ = ["copy_batch", "learn_batch", "terms_batch"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


@_compiled(parallel=True, nogil=True)
def terms_batch(bases: tuple[FloatArray, ...], covs: tuple[FloatArray, ...],
                coefs: tuple[FloatArray, ...], count: int, ns: IntArray, allocs: IntArray,
                x: FloatArray, gamma: float, out: FloatArray, offsets: IntArray) -> None:
    """:func:`.jit_kernels.expert_terms` of the first ``count`` experts, expert ``e``'s
    ``[k, C k, k^T C k, k^T A]`` written at ``out[offsets[e]:]``."""
    for e in prange(count):
        n = ns[e]
        start = offsets[e]
        stop = start + 2 * n + 1 + coefs[e].shape[1]
        out[start:stop] = expert_terms(bases[e], covs[e], coefs[e], x, gamma, n, allocs[e])


@_compiled(parallel=True, nogil=True)
def learn_batch(bases: tuple[FloatArray, ...], coefs: tuple[FloatArray, ...],
                cbufs: tuple[FloatArray, ...], qbufs: tuple[FloatArray, ...], count: int,
                x: FloatArray, ks: FloatArray, cks: FloatArray, dgs: FloatArray, qs: FloatArray,
                rs: FloatArray, cw: FloatArray, rule: FloatArray, e_hats: FloatArray,
                gammas: FloatArray, outcomes: IntArray, diags: FloatArray, dqs: FloatArray,
                dq_mins: FloatArray, dq_argmaxes: IntArray) -> None:
    """Steps 3-5 of learning ``x`` in each of the first ``count`` full experts (``n`` basis
    vectors in buffers for ``n``; docs/learner-math.md §2.5): ``Q k`` and the novelty test
    (:func:`.jit_kernels.projection`, :func:`.jit_kernels.novelty_test` with
    ``rule = [k*, threshold, floor, drift_tol]``), then, for a novel point, the fused
    add-then-delete step (:func:`.jit_fused.fused_step`) while ``Q`` is still in the core's
    cache.  Per expert (one row or entry each): in ``ks``, ``cks``, ``dgs``, ``qs``, ``rs``
    its kernel vector, ``C k``, ``diag(C) + diag(Q)``, Csató's ``K1`` and ``K2``; out
    ``e_hats``, ``gammas``, ``outcomes`` (:data:`.jit.FUSED`; :data:`.jit.KEPT`: not novel,
    left to the caller's projection update; :data:`.jit.DRIFTED`: ``Q`` must be re-inverted
    first, nothing done) and for the fused ones ``diags``, ``dqs``, ``dq_mins``, ``dq_argmaxes`` as
    :func:`.jit_fused.fused_step` returns them."""
    for e in prange(count):
        n = ks.shape[1]
        e_hat, kqk = projection(qbufs[e], ks[e], n, n)
        gamma, drifted, novel = novelty_test(kqk, rule[0], rule[1], rule[2], rule[3])
        e_hats[e] = e_hat
        gammas[e] = gamma
        if drifted:
            outcomes[e] = DRIFTED
        elif not novel:
            outcomes[e] = KEPT
        else:
            outcomes[e] = FUSED
            diag, dq, dq_min, dq_argmax = fused_step(bases[e], coefs[e], cbufs[e], qbufs[e],
                                                     dgs[e], x, cks[e], e_hat, cw, qs[e],
                                                     rs[e], gamma)
            diags[e] = diag
            dqs[e] = dq
            dq_mins[e] = dq_min
            dq_argmaxes[e] = dq_argmax


@_compiled(parallel=True, nogil=True)
def copy_batch(srcs: tuple[FloatArray, ...], dsts: tuple[FloatArray, ...], count: int) -> None:
    """``dsts[e][:] = srcs[e]`` for the first ``count`` pairs: a step's copy-on-write copies
    (:func:`.sogp_batch.copy_many`)."""
    for e in prange(count):
        dsts[e][:] = srcs[e]
