"""Compiled log weights of a step's putatives (numba; paper Algorithm 1, docs/learner-math.md
§4): the GP factor ``log N(y; mu_s(x), s_s^2 I)`` of every evaluated expert and the sum of the
putatives' terms.

Imported through :mod:`.jit` with the other kernels.  The logarithms here are the C library's
(``math.log`` compiled is a call of libm's ``log``), not numpy's: numpy picks its ``log`` and
``exp`` loops by the CPU (AVX-512 ones on this project's EPYC hosts, the C library's on an AVX2
host), so the learned floats depended on the host's SIMD level; with every transcendental of
the learning path compiled, they do not (docs/reproducibility.md, *numpy's SIMD loops*).  Sums
run in index order.  tests/learner/test_jit_weights.py checks each function against a plain
Python oracle (``math.log``, sums in order) bit for bit.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.engine.jit_compile import compiled

__all__ = ["gaussian_log_density", "putative_log_weights", "slot_log_likelihoods"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

LOG_2PI = math.log(2.0 * math.pi)


@compiled(nogil=True)
def gaussian_log_density(sq_err: float, var: float, dims: int) -> float:
    """``log N(y; mu, var I)`` in ``dims`` dimensions from ``sq_err = |y - mu|^2`` (§2.4; with
    ``dims = 1`` for any ``d_y``, Grollman's ``SOGP::log_prob`` constant: fidelity switch 2)."""
    return -0.5 * dims * (LOG_2PI + math.log(var)) - 0.5 * sq_err / var


@compiled(nogil=True)
def slot_log_likelihoods(slots: IntArray, y: FloatArray, means: FloatArray, latent: FloatArray,
                         noise: float, dims: int, slot_ll: FloatArray) -> None:
    """``slot_ll[slots[j]] = log N(y; means[j], (noise + latent[j]) I)`` for every evaluated
    expert ``j`` (the GP factor of its putatives, §4); ``|y - mean|^2`` summed in index order."""
    for j in range(slots.shape[0]):
        sq = 0.0
        for a in range(y.shape[0]):
            r = y[a] - means[j, a]
            sq += r * r
        slot_ll[slots[j]] = gaussian_log_density(sq, noise + latent[j], dims)


@compiled(nogil=True)
def putative_log_weights(base: FloatArray, flat_slots: IntArray, slot_ll: FloatArray,
                         new_ll: float) -> FloatArray:
    """Every putative's log weight: ``base[j]`` (particle weight, CRP prior and gate:
    :func:`.jit_layout.putative_layout`) plus its GP factor, ``slot_ll`` of its slot or
    ``new_ll`` for a new expert (``flat_slots[j] < 0``)."""
    out = np.empty(base.shape[0])
    for j in range(base.shape[0]):
        s = flat_slots[j]
        out[j] = base[j] + (new_ll if s < 0 else slot_ll[s])
    return out
