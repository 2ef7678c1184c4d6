"""The fused add-then-delete step of one full expert, compiled (numba; docs/learner-math.md
§2.5 step 4b and §2.7, :mod:`.sogp_fused`).

Imported through :mod:`.jit` with :mod:`.jit_kernels`, whose packed row, rank update and
min/argmax kernels it calls.  Split from :mod:`.jit_kernels` to keep modules short.  Tested
against the unfused steps (tests/learner/test_jit.py, tests/learner/test_sogp.py).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.jit_compile import compiled as _compiled
from roger_daemon.learner.jit_kernels import min_argmax, rank_update_cq, sym_row

__all__ = ["fused_delete_index", "fused_step"]

FloatArray = npt.NDArray[np.float64]


@_compiled(fastmath={"contract"}, nogil=True)
def fused_delete_index(coef: FloatArray, dg: FloatArray, ck: FloatArray, e: FloatArray,
                       cw: FloatArray, q: FloatArray, r: float, inv_gamma: float,
                       n: int) -> int:
    """The BV the fused step deletes: ``argmin |A1_i|^2 / (Q1_ii + C1_ii)`` over the ``n + 1``
    BVs after the addition (index ``n``: the new one), as :mod:`.sogp_fused` describes;
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
def fused_step(basis: FloatArray, coef: FloatArray, cbuf: FloatArray, qbuf: FloatArray,
               dg: FloatArray, x: FloatArray, ck: FloatArray, e: FloatArray, cw: FloatArray,
               q: FloatArray, r: float, gamma: float
               ) -> tuple[FloatArray, FloatArray, float, int]:
    """One full expert's fused add-then-delete step (:func:`.sogp_fused.fused_add_delete`),
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
