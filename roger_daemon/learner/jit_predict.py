"""Several experts' predictions in one compiled call (paper Algorithm 2, docs/learner-math.md §6).

A prediction evaluates every expert of the MAP particle at one input: the AIBO experiment's
~13 small experts cost ~4 µs of compiled work each but ~10 µs each through
:meth:`.sogp.SparseOnlineGP.predict` (a call, slicing, a tuple).  :func:`predict_experts` runs
the same kernel, :func:`.jit_kernels.expert_terms`, for up to :data:`.jit.WIDTH` experts per
call and finishes each expert's mean and variance as :meth:`.sogp.SparseOnlineGP.terms` and
``predict`` do, operation for operation, so the floats are theirs, bit for bit
(tests/learner/test_jit.py).  One thread: a prediction is latency-bound and small.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.jit_compile import compiled as _compiled
from roger_daemon.learner.jit_kernels import expert_terms

__all__ = ["predict_experts"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


@_compiled(nogil=True)
def predict_experts(bases: tuple[FloatArray, ...], covs: tuple[FloatArray, ...],
                    coefs: tuple[FloatArray, ...], priors: tuple[FloatArray, ...], count: int,
                    ns: IntArray, allocs: IntArray, x: FloatArray, gamma: float, k_star: float,
                    noise: float, floor: float, prior_mean: bool, means: FloatArray,
                    variance: FloatArray) -> None:
    """Predictive mean and variance at ``x`` of the first ``count`` experts (each with
    ``ns[e] >= 1`` basis vectors), written to ``means[e]`` (``d_y``) and ``variance[e]``:
    ``k^T A`` (plus the expert's prior mean ``priors[e]`` when ``prior_mean``) and
    ``noise + max(k* + k^T C k, floor)`` (the sign of ``k^T C k``: docs/learner-math.md §2.4)."""
    d_y = means.shape[1]
    for e in range(count):
        n = ns[e]
        packed = expert_terms(bases[e], covs[e], coefs[e], x, gamma, n, allocs[e])
        base = 2 * n + 1
        if prior_mean:
            prior = priors[e]
            for c in range(d_y):
                means[e, c] = packed[base + c] + prior[c]
        else:
            for c in range(d_y):
                means[e, c] = packed[base + c]
        latent = k_star + packed[2 * n]
        if floor > latent:  # Python's max(latent, floor), NaN included
            latent = floor
        variance[e] = noise + latent
