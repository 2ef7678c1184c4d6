"""The fused add-then-delete step of one full expert, compiled (numba; docs/learner-math.md
§2.5 step 4b and §2.7).

With continuous data nearly every point is novel, so a full expert (``n = beta``) adds a basis
vector and deletes one at every step.  :func:`fused_step` does both in place on the packed
``C`` and ``Q`` (:mod:`.packed`).  With ``s = [Ck; 1]`` and ``e = [Qk; -1]`` the (n+1)-BV state
would be ``C1 = C (+) 0 + r s s^T``, ``Q1 = Q (+) 0 + e e^T / gamma``, ``A1 = A (+) 0 + s q^T``
(§2.5 step 4b).  Deleting BV ``i`` (§2.7) needs only column ``i`` and the diagonals of ``C1``
and ``Q1``, which are O(n) from ``C``, ``Q``, ``s`` and ``e``.  The new BV takes the place of
``i``, so with ``q_v``, ``c_v`` the columns of ``Q1``, ``C1`` at ``i`` and ``w = q_v + c_v``
(all permuted so that index n sits at i)::

    C2 = C_z + [s, q_v, w] diag(r, 1/q*, -1/(q* + c*)) [s, q_v, w]^T
    Q2 = Q_z + [e, q_v] diag(1/gamma, -1/q*) [e, q_v]^T
    A2 = A1 - w a*^T / (q* + c*)

(``C_z``: ``C`` with row and column ``i`` zeroed): one rank-3 and one rank-2 in-place update
(:func:`rank_update_cq`) instead of five passes, the whole step (scores, vectors, ``A``,
``B``, the diagonal cache and the one pass over ``C`` and ``Q``) in one call (the numpy
version batched over experts spent ~0.35 ms per ROGER step in ~60 small array calls at beta =
300, issue 11).  Equal to the plain steps, the full update then the deletion, up to round-off
(tests/learner/test_jit.py, tests/learner/test_sogp.py).  Imported through :mod:`.jit`.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.engine.jit_compile import compiled as _compiled
from roger_daemon.learner.engine.jit_kernels import min_argmax, sym_row

__all__ = ["fused_delete_index", "fused_step", "rank_update_cq"]

FloatArray = npt.NDArray[np.float64]


@_compiled(fastmath={"contract"}, nogil=True)
def fused_delete_index(coef: FloatArray, dg: FloatArray, ck: FloatArray, e: FloatArray,
                       cw: FloatArray, q: FloatArray, r: float, inv_gamma: float,
                       n: int) -> int:
    """The BV the fused step deletes: ``argmin |A1_i|^2 / (Q1_ii + C1_ii)`` over the ``n + 1``
    BVs after the addition (index ``n``: the new one), as the module docstring describes;
    the first minimum, or the first NaN (numpy's ``argmin``)."""
    d_a = coef.shape[1]
    qq = 0.0
    for c in range(d_a):
        qq += q[c] * cw[c] * q[c]
    best = math.inf
    idx = -1
    for i in range(n + 1):
        if i < n:
            aq = 0.0
            aa = 0.0
            for c in range(d_a):
                aq += coef[i, c] * (q[c] * cw[c])
                aa += coef[i, c] * coef[i, c] * cw[c]
            num = aa + ck[i] * (2.0 * aq + ck[i] * qq)
            den = dg[i] + (r * (ck[i] * ck[i]) + (e[i] * e[i]) * inv_gamma)
        else:
            num = qq
            den = r + inv_gamma
        v = num / max(den, 1e-300)
        if math.isnan(v):
            return i
        if v < best or idx < 0:
            best = v
            idx = i
    return idx


@_compiled(fastmath={"contract"}, nogil=True)
def rank_update_cq(cbuf: FloatArray, qbuf: FloatArray, n: int, alloc: int, i: int,
                   uc: FloatArray, cc: FloatArray, uq: FloatArray, cq: FloatArray,
                   dq: FloatArray) -> None:
    """Zero row and column ``i`` (none if ``i < 0``), then ``C += uc^T diag(cc) uc`` and
    ``Q += uq^T diag(cq) uq`` on the live ``n x n`` blocks of the packed ``C`` and ``Q``, in
    place, one pass over each upper triangle; ``dq[:n]`` receives the new ``diag(Q)`` as
    stored (the novelty test's drift check and the clean-up read it, docs/performance.md).

    ``uc`` is (3, n), ``uq`` (2, n): the fused add-then-delete step's columns as rows.
    """
    if i >= 0:
        off = 0
        for a in range(i):
            cbuf[off + i - a] = 0.0
            qbuf[off + i - a] = 0.0
            off += alloc - a
        for a in range(n - i):
            cbuf[off + a] = 0.0
            qbuf[off + a] = 0.0
    # Q first: the caller has just read it for Q k, so it is still in the core's cache
    q0, q1 = uq[0], uq[1]
    off = 0
    for a in range(n):
        row = qbuf[off: off + n - a]
        t0, t1 = q0[a:n], q1[a:n]
        w0 = cq[0] * q0[a]
        w1 = cq[1] * q1[a]
        for b in range(n - a):
            row[b] += w0 * t0[b] + w1 * t1[b]
        dq[a] = row[0]
        off += alloc - a
    c0, c1, c2 = uc[0], uc[1], uc[2]
    off = 0
    for a in range(n):
        row = cbuf[off: off + n - a]
        t0, t1, t2 = c0[a:n], c1[a:n], c2[a:n]
        v0 = cc[0] * c0[a]
        v1 = cc[1] * c1[a]
        v2 = cc[2] * c2[a]
        for b in range(n - a):
            row[b] += v0 * t0[b] + v1 * t1[b] + v2 * t2[b]
        off += alloc - a


@_compiled(fastmath={"contract"}, nogil=True)
def fused_step(basis: FloatArray, coef: FloatArray, cbuf: FloatArray, qbuf: FloatArray,
               dg: FloatArray, x: FloatArray, ck: FloatArray, e: FloatArray, cw: FloatArray,
               q: FloatArray, r: float, gamma: float
               ) -> tuple[FloatArray, FloatArray, float, int]:
    """One full expert's fused add-then-delete step (the module docstring),
    in place; returns the new ``diag(C) + diag(Q)`` (tracked), ``diag(Q)`` (as stored) and
    its minimum and first argmax (:func:`min_argmax`).
    The vectors ``s = [Ck; 1]``, ``e = [Qk; -1]`` and the columns ``i`` of ``C1`` and ``Q1``
    are permuted so that index ``n`` sits at ``i``; then ``A``, the diagonal and the basis are
    updated and :func:`rank_update_cq` does the rank-3 and rank-2 updates in one pass.  ``C``
    and ``Q`` are packed (:mod:`.packed`) for as many basis vectors as the expert holds
    (full)."""
    n = basis.shape[0]
    d_a = coef.shape[1]
    inv_gamma = 1.0 / gamma
    idx = fused_delete_index(coef, dg, ck, e, cw, q, r, inv_gamma, n)
    old = idx < n
    s_i = ck[idx] if old else 1.0
    e_i = e[idx] if old else -1.0
    vs = np.empty((4, n))  # s, e, C1[:, i], Q1[:, i], permuted
    for a in range(n):
        vs[0, a] = ck[a]
        vs[1, a] = e[a]
        vs[2, a] = ck[a] * (r * s_i)
        vs[3, a] = e[a] * (e_i * inv_gamma)
    c_n = 1.0 * (r * s_i)  # entry n of C1[:, i] and Q1[:, i]
    q_n = -1.0 * (e_i * inv_gamma)
    if old:
        crow = sym_row(cbuf, n, n, idx)
        qrow = sym_row(qbuf, n, n, idx)
        for a in range(n):
            vs[2, a] += crow[a]
            vs[3, a] += qrow[a]
        c_star = vs[2, idx]
        q_star = vs[3, idx]
        vs[0, idx] = 1.0
        vs[1, idx] = -1.0
        vs[2, idx] = c_n
        vs[3, idx] = q_n
    else:
        c_star = c_n
        q_star = q_n
    a_star = np.empty(d_a)
    for c in range(d_a):
        a_star[c] = q[c] * s_i + (coef[idx, c] if old else 0.0)
    den = q_star + c_star
    inv_den = 1.0 / den if den > 0.0 else 0.0  # broken: Q-only removal
    if old:
        for c in range(d_a):
            coef[idx, c] = 0.0  # the new BV's row (at i) is 0 + 1 * q
    uc = np.empty((3, n))
    uq = np.empty((2, n))
    for a in range(n):
        w = vs[3, a] + vs[2, a]
        for c in range(d_a):
            coef[a, c] += vs[0, a] * q[c] + (-w) * (a_star[c] * inv_den)
        uc[0, a] = vs[0, a]
        uc[1, a] = vs[3, a]
        uc[2, a] = w
        uq[0, a] = vs[1, a]
        uq[1, a] = vs[3, a]
    cc = np.array([r, 1.0 / q_star, -inv_den])
    cq = np.array([inv_gamma, -1.0 / q_star])
    diag = dg.copy()
    if old:
        diag[idx] = 0.0
    for a in range(n):
        diag[a] += (uc[0, a] * uc[0, a] * cc[0] + uc[1, a] * uc[1, a] * cc[1]
                    + uc[2, a] * uc[2, a] * cc[2])
        diag[a] += uq[0, a] * uq[0, a] * cq[0] + uq[1, a] * uq[1, a] * cq[1]
    i = -1
    if old:
        i = idx
        basis[i, :] = x
    dq = np.empty(n)
    rank_update_cq(cbuf, qbuf, n, n, i, uc, cc, uq, cq, dq)
    dq_min, dq_argmax = min_argmax(dq)
    return diag, dq, dq_min, dq_argmax
