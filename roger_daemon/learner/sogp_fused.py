"""The sparse online GP's hot path: "add a basis vector, then delete one" in one pass.

With continuous data nearly every point is novel, so a full expert (``n = beta``) adds a
basis vector and deletes one at every step (docs/learner-math.md §2.5 steps 4b and 5, §2.7).
:func:`fused_add_delete` does both as one rank-3 update of ``C`` and one rank-2 update of ``Q``,
in place by BLAS on the contiguous ``beta x beta`` buffers, batched over the experts updated in
one ROGER step (:func:`.sogp.update_many`).  Split from :mod:`.sogp`, whose private buffers it
updates; numerically it is :meth:`~.sogp.SparseOnlineGP._full_update` then
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
    BLAS update per expert instead of five passes, and all O(n) vector work batched over the
    experts.  Equal to :meth:`SparseOnlineGP._full_update` then
    :meth:`SparseOnlineGP.delete` up to round-off (tested).  ``n_points`` is not touched.
    """
    u = len(gps)
    n = gps[0].n
    d_a = gps[0].a_cols
    # deletion scores count the output columns only, not a prior mean's a1 column
    cw = np.ones(d_a)
    cw[gps[0].d_y:] = 0.0
    rows = np.arange(u)
    s0 = np.array([g.noise for g in gps])
    r = -1.0 / (s0 + latents)  # Csató's K2
    q = (y - means) / (s0 + latents)[:, None]  # Csató's K1
    a_stack = np.stack([g._A for g in gps])  # (u, n, d_a)
    a_flat = a_stack.reshape(u * n, d_a)
    # deletion scores |A1_i|^2 / (Q1_ii + C1_ii) (Csató ogpbvmin.m), A1_i = A_i + s_i q
    qw = q * cw
    aq = np.matmul(a_stack, qw[:, :, None])[:, :, 0]
    aa = ((a_flat * a_flat) @ cw).reshape(u, n)
    qq = np.einsum("ud,ud->u", qw, q)
    inv_gamma = 1.0 / gamma
    num = np.empty((u, n + 1))
    num[:, :n] = aa + cks * (2.0 * aq + cks * qq[:, None])
    num[:, n] = qq
    den_all = np.empty((u, n + 1))
    dg0 = np.stack([g._diag_cq() for g in gps])  # diag(C) + diag(Q)
    den_all[:, :n] = dg0
    den_all[:, :n] += r[:, None] * (cks * cks) + (e_hat * e_hat) * inv_gamma[:, None]
    den_all[:, n] = r + inv_gamma
    idx = np.argmin(num / np.maximum(den_all, 1e-300), axis=1)
    old = idx < n  # an old BV goes (the new one takes its place); else the new one goes
    j_old = rows[old]
    i_old = idx[old]
    # vectors (u, 4, n+1): s = [Ck; 1], e = [Qk; -1], then the columns i of C1 and Q1
    vecs = np.empty((u, 4, n + 1))
    vecs[:, 0, :n] = cks
    vecs[:, 0, n] = 1.0
    vecs[:, 1, :n] = e_hat
    vecs[:, 1, n] = -1.0
    s_i = vecs[rows, 0, idx]
    e_i = vecs[rows, 1, idx]
    vecs[:, 2] = vecs[:, 0] * (r * s_i)[:, None]  # C1[:, i] = C(+)0 [:, i] + r s s_i
    vecs[:, 3] = vecs[:, 1] * (e_i * inv_gamma)[:, None]  # Q1[:, i] = Q(+)0 [:, i] + e e_i / g
    for j, i in zip(j_old.tolist(), i_old.tolist(), strict=True):  # row i == column i
        vecs[j, 2, :n] += gps[j]._C[i]
        vecs[j, 3, :n] += gps[j]._Q[i]
    c_star = vecs[rows, 2, idx]
    q_star = vecs[rows, 3, idx]
    a_star = q * s_i[:, None]
    a_star[old] += a_stack[j_old, i_old]
    den = q_star + c_star
    ok = den > 0.0
    inv_den = np.where(ok, 1.0 / np.where(ok, den, 1.0), 0.0)  # broken: Q-only removal
    # permute: index n moves to position i (for the rows where an old BV goes)
    perm = vecs[:, :, :n]  # a view; fix position i in place
    perm[j_old, :, i_old] = vecs[j_old, :, n]
    w = perm[:, 3] + perm[:, 2]
    a_stack[j_old, i_old] = 0.0  # A1 permuted: the new BV's row (at i) is 0 + 1 * q
    left = np.stack([perm[:, 0], -w], axis=2)  # (u, n, 2)
    right = np.stack([q, a_star * inv_den[:, None]], axis=1)  # (u, 2, d_y)
    a_stack += np.matmul(left, right)
    cols_c = np.empty((u, 3, n))  # cols_c[j].T is Fortran-ordered (n, 3)
    cols_c[:, 0] = perm[:, 0]
    cols_c[:, 1] = perm[:, 3]
    cols_c[:, 2] = w
    coef_c = np.stack([r, 1.0 / q_star, -inv_den], axis=1)
    cols_q = np.empty((u, 2, n))
    cols_q[:, 0] = perm[:, 1]
    cols_q[:, 1] = perm[:, 3]
    coef_q = np.stack([inv_gamma, -1.0 / q_star], axis=1)
    # the diagonals of the new C and Q, for the next step's deletion scores
    diag = dg0
    diag[j_old, i_old] = 0.0
    diag += np.einsum("ukn,uk->un", cols_c * cols_c, coef_c)
    diag += np.einsum("ukn,uk->un", cols_q * cols_q, coef_q)
    for j, gp in enumerate(gps):
        i = -1
        if old[j]:
            i = int(idx[j])
            gp._B[i] = x
            gp._K[i, :] = ks[j]  # the new basis vector's kernel row replaces row i
            gp._K[:, i] = ks[j]
            gp._K[i, i] = gp.kernel.k_star
        gp._A[:n] = a_stack[j]
        # zero row and column i of C and Q, then the rank-3 and rank-2 updates: one pass
        _jit.rank_update_cq(gp._C, gp._Q, n, i, cols_c[j], coef_c[j], cols_q[j], coef_q[j])
        gp._dg = diag[j].copy()
