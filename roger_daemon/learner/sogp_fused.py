"""The sparse online GP's hot path: "add a basis vector, then delete one" in one pass.

With continuous data nearly every point is novel, so a full expert (``n = beta``) adds a
basis vector and deletes one at every step (docs/learner-math.md §2.5 steps 4b and 5, §2.7).
:func:`fused_add_delete` does both as one rank-3 update of ``C`` and one rank-2 update of ``Q``,
in place on the contiguous ``beta x beta`` buffers by one compiled call per expert, for the
experts updated in one ROGER step (:func:`.sogp.update_many`).  Split from :mod:`.sogp`,
whose private buffers it updates; numerically it is :meth:`~.sogp.SparseOnlineGP._full_update` then
:meth:`~.sogp.SparseOnlineGP.delete` up to round-off (tested).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt
from scipy.linalg.blas import dgemm as _dgemm

from roger_daemon.learner import jit as _jit

if TYPE_CHECKING:
    from roger_daemon.learner.sogp import SparseOnlineGP

__all__ = ["add_lowrank", "fused_add_delete"]

FloatArray = npt.NDArray[np.float64]


def add_lowrank(buf: FloatArray, n: int, cols: FloatArray, coefs: FloatArray) -> None:
    """``buf[:n, :n] += cols diag(coefs) cols^T`` (a symmetric rank-m update), in place.

    One BLAS ``dgemm`` updates the whole contiguous buffer in place (``buf`` is symmetric, so
    its transpose is the same matrix in Fortran order); when the live block is smaller than the
    buffer the vectors are zero-padded, which leaves the padding unchanged.  Buffers grow by
    1.5x, so at most ~2.25x the live block is touched; tiny blocks use numpy.
    """
    alloc = buf.shape[0]
    if alloc == n:
        _dgemm(1.0, cols, cols * coefs, 1.0, buf.T, trans_b=True, overwrite_c=True)
    elif n >= 32:
        padded = np.zeros((alloc, cols.shape[1]), order="F")
        padded[:n] = cols
        _dgemm(1.0, padded, padded * coefs, 1.0, buf.T, trans_b=True, overwrite_c=True)
    else:
        buf[:n, :n] += (cols * coefs) @ cols.T


def fused_add_delete(gps: Sequence[SparseOnlineGP], x: FloatArray, y: FloatArray,
                      ks: FloatArray, cks: FloatArray, means: FloatArray, latents: FloatArray,
                      e_hat: FloatArray, gamma: FloatArray) -> None:
    """Full update to n + 1 BVs then one KL-optimal deletion, for u full experts at once.

    With ``s = [Ck; 1]`` and ``e = [Q k; -1]`` the (n+1)-BV state would be
    ``C1 = C (+) 0 + r s s^T``, ``Q1 = Q (+) 0 + e e^T / gamma``, ``A1 = A (+) 0 + s q^T``
    (docs/learner-math.md §2.5 step 4b).  Deleting BV ``i`` (§2.7) needs only column ``i`` and the
    diagonals of ``C1`` and ``Q1``, which are O(n) from ``C``, ``Q``, ``s`` and ``e``.  The new
    BV takes the place of ``i``, so with ``q_v``, ``c_v`` the columns of ``Q1``, ``C1`` at
    ``i`` and ``w = q_v + c_v`` (all permuted so that index n sits at i)::

        C2 = C_z + [s, q_v, w] diag(r, 1/q*, -1/(q* + c*)) [s, q_v, w]^T
        Q2 = Q_z + [e, q_v] diag(1/gamma, -1/q*) [e, q_v]^T
        A2 = A1 - w a*^T / (q* + c*)

    (``C_z``: ``C`` with row and column ``i`` zeroed): one rank-3 and one rank-2 in-place
    update per expert instead of five passes.  Each expert's whole step (scores, vectors,
    ``A``, ``B``, ``K_B``, the diagonal cache and the one pass over ``C`` and ``Q``) is one
    compiled call, :func:`.jit_kernels.fused_step` (the numpy version batched over experts
    spent ~0.35 ms per ROGER step in ~60 small array calls at beta = 300, issue 11).
    Equal to :meth:`SparseOnlineGP._full_update` then :meth:`SparseOnlineGP.delete` up to
    round-off (tested).  ``n_points`` is not touched.
    """
    d_a = gps[0].a_cols
    # deletion scores count the output columns only, not a prior mean's a1 column
    cw = np.ones(d_a)
    cw[gps[0].d_y:] = 0.0
    s0 = np.array([g.noise for g in gps])
    r = -1.0 / (s0 + latents)  # Csató's K2
    q = (y - means) / (s0 + latents)[:, None]  # Csató's K1
    kstar = gps[0].kernel.k_star
    # one compiled call per expert: scores, the rank-3 and rank-2 updates, A, B, K_B, diag
    for j, gp in enumerate(gps):
        gp._dg = _jit.fused_step(gp._B, gp._A, gp._C, gp._Q, gp._K, gp._diag_cq(), x, ks[j],
                                 cks[j], e_hat[j], cw, q[j], float(r[j]), float(gamma[j]),
                                 kstar)
