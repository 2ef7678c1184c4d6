"""One expert's update steps in one call each (:mod:`.sogp_steps`, :mod:`.sogp`).

With small experts (the AIBO experiment's broad kernel keeps ~15 basis vectors) the projection
update, the prior mean's shift, the novelty test and a re-inversion of ``Q`` were a handful of
numpy or kernel calls each, ~20 µs of per-call overhead for a few hundred flops. These kernels
do each in one call and give the same floats as before, bit for bit
(tests/learner/test_jit.py): :func:`sparse_update` and :func:`shift_mean` make numpy's
elementwise operations in its order (no ``fastmath``, so no fused multiply-adds, and no
reductions); :func:`novelty_step` and :func:`refresh_inverse` call the kernels the separate
calls made.  At the paper's parameters an expert that is not yet full (~0.8 of the ~10 a step
updates on the benchmark stream) learns by :func:`growth_step`, the same floats as the dozen
calls it replaced (tests/learner/test_growth_step.py), and its buffers grow by
:func:`grow_slab`, a Python loop over the rows of ``C`` and ``Q`` before (~0.25 ms a growth).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.engine.jit_cholesky import cholesky_inverse
from roger_daemon.learner.engine.jit_compile import compiled as _compiled
from roger_daemon.learner.engine.jit_constants import ADDED, DRIFTED, NEEDS_ROOM, PROJECTED
from roger_daemon.learner.engine.jit_evaluate import slab_views
from roger_daemon.learner.engine.jit_kernels import (
    gram_matrix,
    keeps_basis_vectors,
    min_argmax,
    novelty_test,
    packed_add_lowrank,
    projection,
)

__all__ = ["add_basis_vector", "dot_column", "grow_slab", "growth_step", "novelty_step",
           "refresh_inverse", "shift_mean", "sparse_update"]

FloatArray = npt.NDArray[np.float64]


@_compiled(nogil=True)
def sparse_update(coef: FloatArray, cbuf: FloatArray, alloc: int, n: int, ck: FloatArray,
                  e_hat: FloatArray, q: FloatArray, r: float, eta: float) -> None:
    """The projection update (docs/learner-math.md §2.5 step 4a) of the live ``n`` rows:
    ``s = C k + e``, ``A += (s q^T) eta``, ``C += (r eta) s s^T`` (packed ``C``, in place)."""
    s_hat = np.empty(n)
    for i in range(n):
        s_hat[i] = ck[i] + e_hat[i]
    for i in range(n):
        si = s_hat[i]
        for j in range(q.shape[0]):
            coef[i, j] += (si * q[j]) * eta
    packed_add_lowrank(cbuf, alloc, n, s_hat.reshape((1, n)), np.array([r * eta]))


@_compiled(nogil=True)
def shift_mean(coef: FloatArray, mean: FloatArray, y: FloatArray, n: int, n_points: int,
               out: FloatArray) -> None:
    """The prior mean's shift after learning ``y`` (its ``d`` outputs): ``dm = (y - m) /
    n_points``, ``out = m + dm`` and ``A[:n, :d] -= a1 dm^T`` with ``a1 = A[:n, d]``."""
    d = out.shape[0]
    dm = np.empty(d)
    for j in range(d):
        dm[j] = (y[j] - mean[j]) / n_points
        out[j] = mean[j] + dm[j]
    for i in range(n):
        a1 = coef[i, d]
        for j in range(d):
            coef[i, j] -= a1 * dm[j]


@_compiled(nogil=True, inline="always")
def _packed_diagonal(buf: FloatArray, n: int, alloc: int) -> FloatArray:
    """The diagonal of the live ``n x n`` block of the packed ``buf`` (a copy; row ``a`` starts
    ``alloc - (a - 1)`` after row ``a - 1``, :mod:`.packed`): :func:`.packed.diagonal`
    compiled."""
    out = np.empty(n)
    off = 0
    for a in range(n):
        out[a] = buf[off]
        off += alloc - a
    return out


@_compiled(nogil=True)
def novelty_step(qbuf: FloatArray, k: FloatArray, n: int, alloc: int, kstar: float,
                 threshold: float, floor: float, drift_tol: float
                 ) -> tuple[FloatArray, float, bool, bool]:
    """Step 3 (docs/learner-math.md §2.5) for the packed ``Q``: ``(Q k, gamma, drifted,
    novel)`` by :func:`.jit_kernels.projection` and :func:`.jit_kernels.novelty_test`, where
    ``drifted`` also holds when ``Q``'s diagonal shows drift (``min_i Q_ii k* < 1 -
    drift_tol``; :meth:`.sogp_steps.SOGPSteps.q_drifted`)."""
    e_hat, kqk = projection(qbuf, k, n, alloc)
    gamma, drifted, novel = novelty_test(kqk, kstar, threshold, floor, drift_tol)
    if not drifted and n > 0:
        low, _ = min_argmax(_packed_diagonal(qbuf, n, alloc))  # numpy's min: NaN if any is
        drifted = low * kstar < 1.0 - drift_tol
    return e_hat, gamma, drifted, novel


@_compiled(nogil=True)
def refresh_inverse(basis: FloatArray, gamma: float, n: int, jitter: float, qbuf: FloatArray,
                    alloc: int) -> bool:
    """``Q = (K_B + jitter I)^{-1}`` re-inverted (docs/learner-math.md, matrix drift): ``K_B``
    of the live basis (:func:`.jit_kernels.gram_matrix`), its inverse by
    :func:`.jit_kernels.cholesky_inverse`, stored as the packed upper triangle of ``qbuf``;
    False (``qbuf`` untouched) if the factorisation fails."""
    inverse = np.empty((n, n))
    if not cholesky_inverse(gram_matrix(basis, gamma, n), n, jitter, inverse):
        return False
    off = 0
    for a in range(n):
        for b in range(a, n):
            qbuf[off + b - a] = inverse[a, b]
        off += alloc - a
    return True


@_compiled(nogil=True)
def add_basis_vector(basis: FloatArray, coef: FloatArray, cbuf: FloatArray, qbuf: FloatArray,
                     alloc: int, n: int, x: FloatArray, ck: FloatArray, e_hat: FloatArray,
                     q: FloatArray, r: float, gamma: float) -> None:
    """Step 4b (Csató thesis eq. 2.46; ``Q`` by eq. 3.5; docs/learner-math.md §2.5): ``x``
    becomes basis vector ``n`` of an expert whose buffers hold at least ``n + 1``, in place.
    With ``s = [C k, 1]`` and ``e = [Q k, -1]``: ``A += s q^T`` (row ``n`` first zeroed),
    ``C += r s s^T``, ``Q += e e^T / gamma``, row and column ``n`` of the packed ``C`` and ``Q``
    first zeroed (stale after a deletion).  The one implementation of the step: an expert
    that is not full takes it inside :func:`growth_step`, one whose buffers had to grow first
    from :meth:`.sogp_steps.SOGPSteps._full_update`.  No ``fastmath``: numpy's outer product,
    then the sum, bit for bit."""
    basis[n, :] = x
    s = np.empty(n + 1)  # [C k, 1] and [Q k, -1]
    e = np.empty(n + 1)
    s[:n] = ck
    s[n] = 1.0
    e[:n] = e_hat
    e[n] = -1.0
    coef[n, :] = 0.0
    for i in range(n + 1):  # A += s q^T: numpy's outer product, then the sum
        for j in range(q.shape[0]):
            coef[i, j] += s[i] * q[j]
    off = 0
    for a in range(n + 1):  # column n of the upper triangles
        cbuf[off + n - a] = 0.0
        qbuf[off + n - a] = 0.0
        off += alloc - a
    packed_add_lowrank(cbuf, alloc, n + 1, s.reshape((1, n + 1)), np.array([r]))
    packed_add_lowrank(qbuf, alloc, n + 1, e.reshape((1, n + 1)), np.array([1.0 / gamma]))


@_compiled(nogil=True)
def growth_step(basis: FloatArray, coef: FloatArray, cbuf: FloatArray, qbuf: FloatArray,
                alloc: int, n: int, x: FloatArray, k: FloatArray, ck: FloatArray,
                q: FloatArray, r: float, kstar: float, threshold: float, floor: float,
                drift_tol: float, cleanup_floor: float) -> tuple[int, float, bool]:
    """Steps 3, 4 and step 6's test of learning ``x`` in an expert that is not full
    (docs/learner-math.md §2.5-§2.7), in one call: what :meth:`.sogp.SparseOnlineGP.update`
    did in numpy and kernel calls, the same floats.  In: the kernel vector ``k``, ``C k``,
    Csató's ``K1`` (``q``) and ``K2`` (``r``).  :func:`novelty_step`; not novel: the
    projection update (:func:`sparse_update`); novel, with room in the buffers: ``x`` becomes
    basis vector ``n`` (:func:`add_basis_vector`).  Returns ``(outcome, gamma, clean)``: the
    outcome :data:`.jit.ADDED`, :data:`.jit.PROJECTED`, :data:`.jit.DRIFTED` or
    :data:`.jit.NEEDS_ROOM` (both: nothing changed), and whether the geometric clean-up keeps
    every basis vector (:func:`.jit_kernels.keeps_basis_vectors` of the largest ``Q_ii``,
    false if one is NaN)."""
    e_hat, gamma, drifted, novel = novelty_step(qbuf, k, n, alloc, kstar, threshold, floor,
                                                drift_tol)
    if drifted:
        return DRIFTED, gamma, False
    if not novel:
        sparse_update(coef, cbuf, alloc, n, ck, e_hat, q, r, 1.0 / (1.0 + gamma * r))
        outcome = PROJECTED
    elif n == alloc:
        return NEEDS_ROOM, gamma, False
    else:
        add_basis_vector(basis, coef, cbuf, qbuf, alloc, n, x, ck, e_hat, q, r, gamma)
        n += 1
        outcome = ADDED
    if n <= 1:
        return outcome, gamma, True
    diag = _packed_diagonal(qbuf, n, alloc)
    _, first_max = min_argmax(diag)  # np.argmax's: the first NaN if there is one
    return outcome, gamma, keeps_basis_vectors(diag[first_max], cleanup_floor)


@_compiled(nogil=True)
def grow_slab(old: FloatArray, new: FloatArray, n: int) -> None:
    """An expert's ``n`` basis vectors moved from slab ``old`` into the larger ``new`` (both
    laid out as their headers say, :mod:`.jit_slab`; ``new`` zeroed): the rows of ``B`` and
    ``A``, the prior mean, and each row of the packed ``C`` and ``Q`` to where the new
    ``alloc`` puts it (:meth:`.sogp_steps.SOGPSteps._grow`)."""
    c_old, q_old, b_old, a_old, m_old = slab_views(old)
    c_new, q_new, b_new, a_new, m_new = slab_views(new)
    b_new[:n] = b_old[:n]
    a_new[:n] = a_old[:n]
    m_new[:] = m_old
    alloc_old, alloc_new = b_old.shape[0], b_new.shape[0]
    src = 0
    dst = 0
    for i in range(n):
        c_new[dst: dst + n - i] = c_old[src: src + n - i]
        q_new[dst: dst + n - i] = q_old[src: src + n - i]
        src += alloc_old - i
        dst += alloc_new - i


@_compiled(nogil=True)
def dot_column(k: FloatArray, coef: FloatArray, col: int, n: int) -> float:
    """``k[:n] . coef[:n, col]``, summed in index order: the prior mean's ``a1^T k``
    (:meth:`.sogp.SparseOnlineGP._targets`) and, with ``y`` as a one-column view, the empty
    expert's ``|y|^2`` (:func:`.roger_step.putatives`); the same floats on every host.  BLAS's
    dot sums in an order its CPU kernel chooses: measured, OpenBLAS's ``Haswell`` and ``Zen``
    kernels give these bits below 16 entries, its ``SkylakeX`` kernel only for one."""
    t = 0.0
    for i in range(n):
        t += k[i] * coef[i, col]
    return t
