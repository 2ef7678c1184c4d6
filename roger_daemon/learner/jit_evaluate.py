"""Several experts at one input in one compiled call: a step's evaluation (paper Algorithm 1,
docs/learner-math.md §4) and a prediction's multimap (Algorithm 2, §6).

Both evaluate many small experts at one point: the AIBO experiment's ~25 experts of ~10 basis
vectors cost ~1.5 µs of compiled work each but ~7–10 µs each through
:meth:`.sogp.SparseOnlineGP.terms` (a call, slicing, a tuple).  :func:`evaluate_experts` runs
the same kernel, :func:`.jit_kernels.expert_terms`, for up to :data:`.jit.WIDTH` experts per
call and finishes each expert's mean and latent variance as :meth:`.sogp.SparseOnlineGP.terms`
does, operation for operation (:func:`summarise`), so the floats are its, bit for bit
(tests/learner/test_jit.py).  One thread: the experts are small; large experts on several
threads go to :func:`.jit_batch.terms_batch`, which finishes them with :func:`summarise` too.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.jit_compile import compiled as _compiled
from roger_daemon.learner.jit_kernels import expert_terms

__all__ = ["evaluate_experts", "summarise"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


@_compiled(nogil=True)
def summarise(packed: FloatArray, n: int, prior: FloatArray, k_star: float, floor: float,
              prior_mean: bool, mean_out: FloatArray) -> float:
    """From one expert's ``[k, C k, k^T C k, k^T A]`` (:func:`.jit_kernels.expert_terms`):
    its predictive mean into ``mean_out`` (``k^T A``, plus the prior mean ``prior`` when
    ``prior_mean``), and its latent variance ``max(k* + k^T C k, floor)`` returned (the sign of
    ``k^T C k``: docs/learner-math.md §2.4), as :meth:`.sogp.SparseOnlineGP.terms` makes them."""
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


@_compiled(nogil=True)
def evaluate_experts(bases: tuple[FloatArray, ...], covs: tuple[FloatArray, ...],
                     coefs: tuple[FloatArray, ...], priors: tuple[FloatArray, ...], count: int,
                     ns: IntArray, allocs: IntArray, x: FloatArray, gamma: float,
                     k_star: float, floor: float, prior_mean: bool, out: FloatArray,
                     offsets: IntArray, means: FloatArray, latent: FloatArray) -> None:
    """The first ``count`` experts (each with ``ns[e] >= 1`` basis vectors) at ``x``: expert
    ``e``'s ``[k, C k, k^T C k, k^T A]`` written at ``out[offsets[e]:]``, its predictive mean
    into ``means[e]`` and its latent variance into ``latent[e]`` (:func:`summarise`)."""
    for e in range(count):
        n = ns[e]
        packed = expert_terms(bases[e], covs[e], coefs[e], x, gamma, n, allocs[e])
        start = offsets[e]
        out[start: start + packed.shape[0]] = packed
        latent[e] = summarise(packed, n, priors[e], k_star, floor, prior_mean, means[e])
