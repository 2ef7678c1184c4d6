"""The sparse online GP's matrix steps: projection and full updates, deletion, clean-up, the
re-inversion of ``Q``, the prior mean's shift (Csató thesis eq. 2.46, App. G;
docs/learner-math.md §2.5-§2.7), and the rest of a step whose steps 3-5 ran batched.

A base class of :class:`.sogp.SparseOnlineGP`, split from it: these methods change the buffers
``_B``, ``_A``, ``_Cp``, ``_Qp`` in place; the class there owns them, predicts and
dispatches :meth:`~.sogp.SparseOnlineGP.update` to these steps.  ``C`` and ``Q`` are stored
packed (their upper triangles, :mod:`.engine.packed`) in buffers sized for ``_alloc`` basis
vectors; all the buffers are views of one slab per expert (:meth:`SOGPSteps._bind`,
:mod:`.engine.jit_slab`).  The arithmetic is the engine's compiled kernels (:mod:`.engine`).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy.linalg.lapack import dpotrf as _dpotrf
from scipy.linalg.lapack import dpotri as _dpotri

from roger_daemon.learner.engine import jit as _jit
from roger_daemon.learner.engine import jit_slab
from roger_daemon.learner.engine import packed as _packed
from roger_daemon.learner.kernel import RBFKernel

__all__ = ["GAMMA_FLOOR", "LATENT_FLOOR", "NEAR_DEPENDENT", "SOGPSteps"]

FloatArray = npt.NDArray[np.float64]

LATENT_FLOOR = 1e-12  # clamp of k* + k^T C k (Grollman, OTL, Csató)
GAMMA_FLOOR = 1e-12  # projection residuals below this count as 0 (learner-math.md §2.5 step 3)
# Q = K_B^-1 is kept by rank-1 updates and drifts when K_B is ill-conditioned (pitfall 6: a
# broad kernel and a small novelty threshold admit near-duplicate basis vectors). Two O(n)
# consistency checks that exact arithmetic guarantees trigger a re-inversion from the basis:
# gamma = k* - k^T Q k >= 0 (a squared distance), and Q_ii >= 1/K_ii = 1/k*.
_Q_DRIFT_TOL = 1e-6
NEAR_DEPENDENT = 1e-3  # a basis vector added with gamma below this (x k*) re-inverts Q
_Q_JITTER = 1e-10  # times k*: first jitter tried if K_B's Cholesky factorisation fails


class SOGPSteps:
    """The in-place matrix steps of a sparse online GP (state: :class:`.sogp.SparseOnlineGP`)."""

    __slots__ = ("d_x", "d_y", "kernel", "noise", "capacity", "novelty_threshold", "normaliser",
                 "fused", "n", "n_points", "_alloc", "slab", "_B", "_A", "_Cp", "_Qp", "_dg",
                 "_dq", "_dq_min", "_dq_argmax", "q_refreshes", "prior_mean", "_m",
                 "novelty_margin", "home")
    kernel: RBFKernel
    capacity: int | None
    novelty_threshold: float
    fused: bool
    d_x: int
    d_y: int
    prior_mean: bool
    n: int
    n_points: int
    noise: float
    q_refreshes: int
    novelty_margin: float
    home: int  # the batched kernels' thread whose cache holds it (-1: none yet)
    _alloc: int
    slab: FloatArray  # every buffer below is a view of it (:meth:`_bind`)
    _B: FloatArray
    _A: FloatArray
    _Cp: FloatArray
    _Qp: FloatArray
    _dg: FloatArray | None
    _dq: FloatArray | None
    _dq_min: float  # min and first argmax of _dq (valid while _dq is not None)
    _dq_argmax: int
    _m: FloatArray

    @property
    def a_cols(self) -> int:
        """Columns of the coefficient buffer: ``d_y``, plus ``a1`` with a prior mean."""
        return self.d_y + 1 if self.prior_mean else self.d_y

    def targets(self, y: FloatArray, mean: FloatArray, k: FloatArray
                ) -> tuple[FloatArray, FloatArray]:
        """``(y, mean)`` extended by the ``a1`` column (target 1, prediction ``a1^T k``).

        ``y - mean`` is then the residual of every column of ``A``: with a prior mean the
        columns model ``y - m`` and predict ``mean - m``, whose difference is ``y - mean``.
        """
        if not self.prior_mean:
            return y, mean
        d = self.d_y
        ext = np.empty((2, d + 1))  # [y, 1] and [mean, a1^T k] (cheaper than two np.append)
        ext[0, :d] = y
        ext[0, d] = 1.0
        ext[1, :d] = mean
        ext[1, d] = _jit.dot_column(k, self._A, d, self.n)  # a1^T k, no BLAS
        return ext[0], ext[1]

    def _shift_mean(self, y: FloatArray) -> None:
        """After learning ``y``: move ``m`` to the new running mean, ``A <- A - a1 dm^T``."""
        if not self.prior_mean:
            return
        # dm = (y - m) / n_points; m + dm; A[:, :d] -= a1 dm^T: numpy's floats, one call, the
        # new mean written over the old one in the slab
        _jit.shift_mean(self._A, self._m, y, self.n, self.n_points, self._m)

    def novelty(self, k: FloatArray) -> tuple[FloatArray, float, bool]:
        """Step 3 (docs/learner-math.md §2.5): ``(Q k, gamma, novel)`` with the projection
        residual ``gamma = k* - k^T Q k`` of the kernel vector ``k``, after re-inverting ``Q``
        if it has visibly drifted, 0 below :data:`GAMMA_FLOOR`, and whether the point is
        novel (a full update, step 4b) by :func:`.jit_kernels.novelty_test`.  Records
        :attr:`novelty_margin`."""
        # projection, the test and Q's diagonal checked for drift in one call
        e_hat, gamma, drifted, novel = _jit.novelty_step(
            self._Qp, k, self.n, self._alloc, *self.novelty_constants())
        if drifted:
            self.refresh_inverse_gram()
            e_hat, kqk = _jit.projection(self._Qp, k, self.n, self._alloc)
            gamma, _, novel = _jit.novelty_test(kqk, *self.novelty_constants())
        self.record_novelty_margin(gamma)
        return e_hat, gamma, novel

    def record_novelty_margin(self, gamma: float) -> None:
        """:attr:`novelty_margin` of a novelty test that gave ``gamma``
        (:func:`.jit_kernels.novelty_margin`)."""
        self.novelty_margin = _jit.novelty_margin(gamma, self.kernel.k_star,
                                                  self.novelty_threshold)

    def cleanup_floor(self) -> float:
        """The geometric clean-up's bound on ``1 / Q_ii`` (step 6,
        :func:`.jit_kernels.keeps_basis_vectors`): the novelty threshold times 1e-3."""
        return self.novelty_threshold * 1e-3

    def novelty_constants(self) -> tuple[float, float, float, float]:
        """``(k*, threshold, floor, drift_tol)``: :func:`.jit_kernels.novelty_test`'s
        arguments besides ``k^T Q k``."""
        return self.kernel.k_star, self.novelty_threshold, GAMMA_FLOOR, _Q_DRIFT_TOL

    def q_drifted(self) -> bool:
        """True when ``Q``'s diagonal shows drift from ``K_B^-1``: ``Q_ii >= 1/K_ii = 1/k*``
        in exact arithmetic (see ``_Q_DRIFT_TOL``; the residual's own check is in
        :func:`.jit_kernels.novelty_test`)."""
        kstar = self.kernel.k_star
        if self._dq is not None:  # the fused step's copy, with its minimum
            return self._dq_min * kstar < 1.0 - _Q_DRIFT_TOL
        diag = self._diag_q()
        return bool(diag.size and float(diag.min()) * kstar < 1.0 - _Q_DRIFT_TOL)

    def refresh_inverse_gram(self) -> None:
        """Re-invert ``Q = K_B^-1`` by Cholesky (docs/learner-math.md, matrix drift).

        Only ``Q`` is a function of the basis alone; ``A`` and ``C`` carry the data and are kept.
        ``K_B`` is recomputed from the basis (:meth:`_gram_matrix`, the same floats as the
        kernel vectors computed when each basis vector entered); LAPACK ``dpotrf`` then
        ``dpotri`` (the inverse from the factor, lower triangle mirrored, so ``Q`` is exactly
        symmetric).  Counted in :attr:`q_refreshes`.
        """
        n = self.n
        jitter = 0.0
        if n <= _jit.SMALL:  # compiled, in one call: no LAPACK call overhead at this size
            while not _jit.refresh_inverse(self._B, self.kernel.gamma, n, jitter, self._Qp,
                                           self._alloc):
                jitter = max(10.0 * jitter, _Q_JITTER * self.kernel.k_star)
            self._forget_diagonals()
            self.q_refreshes += 1
            return
        gram = self._gram_matrix()
        while True:  # K_B is SPD in exact arithmetic; add jitter only if round-off says no
            factor, info = _dpotrf(gram if jitter == 0.0 else gram + jitter * np.eye(n),
                                   lower=1, clean=0)
            if info == 0:
                break
            jitter = max(10.0 * jitter, _Q_JITTER * self.kernel.k_star)
        inv, _ = _dpotri(factor, lower=1, overwrite_c=1)
        # the lower triangle holds the inverse: stored as the upper one of its transpose
        _packed.pack_into(self._Qp, self._alloc, np.ascontiguousarray(inv.T), n)
        self._forget_diagonals()
        self.q_refreshes += 1

    def _gram_matrix(self) -> FloatArray:
        """``K_B`` (n, n) of the live basis, recomputed: not kept, so that a copy-on-write copy
        moves two packed matrices, not three (docs/performance.md, *K_B recomputed*)."""
        gram: FloatArray = _jit.gram_matrix(self._B, self.kernel.gamma, self.n)
        return gram

    def _forget_diagonals(self) -> None:
        """``C`` or ``Q`` is about to change: drop the cached diagonals."""
        self._dg = None
        self._dq = None

    def _diag_q(self) -> FloatArray:
        """``diag(Q)`` as stored: the fused step's copy (read-only use) or read off ``Q``."""
        if self._dq is not None:
            return self._dq
        return _packed.diagonal(self._Qp, self._alloc, self.n)

    def diag_cq(self) -> FloatArray:
        """``diag(C) + diag(Q)`` (cached by the fused hot path, else read off the matrices)."""
        if self._dg is not None:
            return self._dg
        n = self.n
        return (_packed.diagonal(self._Cp, self._alloc, n)
                + _packed.diagonal(self._Qp, self._alloc, n))

    def fusable(self) -> bool:
        """Full, in buffers sized for exactly ``beta``: the fused add-then-delete hot path
        applies."""
        return (self.fused and self.capacity is not None and self.n == self.capacity
                and self._alloc == self.n)

    def _sparse_update(self, ck: FloatArray, e_hat: FloatArray, gamma: float, r: float,
                       q: FloatArray) -> None:
        """Step 4a: projection update, BV set unchanged; ``eta = 1/(1 + gamma r)``."""
        self._forget_diagonals()
        eta = 1.0 / (1.0 + gamma * r)
        # s = C k + e; A += (s q^T) eta; C += (r eta) s s^T: numpy's floats, one call
        _jit.sparse_update(self._A, self._Cp, self._alloc, self.n, ck, e_hat, q, r, eta)

    def _clean_up(self) -> None:
        """Steps 5 and 6: ``while n > beta`` delete; geometric clean-up (Csató)."""
        if self.capacity is not None:
            while self.n > self.capacity:
                self.delete(self._deletion_choice())
        floor = self.cleanup_floor()
        while self.n > 1 and floor > 0.0:
            diag = self._diag_q()
            i = self._dq_argmax if self._dq is not None else int(np.argmax(diag))
            if _jit.keeps_basis_vectors(float(diag[i]), floor):
                break
            self.delete(i)

    def _full_update(self, x: FloatArray, ck: FloatArray, e_hat: FloatArray,
                     gamma: float, r: float, q: FloatArray) -> None:
        """Step 4b: x becomes basis vector n, the buffers grown first if they are full
        (:func:`.engine.jit_small.add_basis_vector`, thesis eq. 2.46; Q by eq. 3.5)."""
        n = self.n
        self._forget_diagonals()
        self._grow(n + 1)
        _jit.add_basis_vector(self._B, self._A, self._Cp, self._Qp, self._alloc, n, x, ck,
                              e_hat, q, r, gamma)
        self.n = n + 1

    def _fused_add_delete(self, x: FloatArray, ck: FloatArray, e_hat: FloatArray,
                          gamma: float, r: float, q: FloatArray) -> None:
        """Steps 4b and 5 fused at capacity (docs/learner-math.md §2.5 step 4b, §2.7): the
        full update to ``n + 1`` basis vectors, then one KL-optimal deletion, in place, as one
        rank-3 update of ``C`` and one rank-2 update of ``Q`` in one compiled call
        (:func:`.engine.jit_fused.fused_step`, whose docstring derives it).

        With ``s = [Ck; 1]`` and ``e = [Q k; -1]`` the (n+1)-BV state would be
        ``C1 = C (+) 0 + r s s^T``, ``Q1 = Q (+) 0 + e e^T / gamma``, ``A1 = A (+) 0 + s q^T``;
        deleting BV ``i`` needs only column ``i`` and the diagonals of ``C1`` and ``Q1``, O(n)
        from ``C``, ``Q``, ``s`` and ``e``; the new BV takes the place of ``i``.  Equal to
        :meth:`_full_update` then :meth:`delete` up to round-off (tested); ``n_points`` is not
        touched.  ``r``, ``q``: Csató's ``K2`` and ``K1`` (with a prior mean, ``q`` has the
        ``a1`` column too)."""
        self._dg, self._dq, self._dq_min, self._dq_argmax = _jit.fused_step(
            self._B, self._A, self._Cp, self._Qp, self.diag_cq(), x, ck, e_hat,
            jit_slab.output_weights(self.a_cols, self.d_y), q, r, gamma)

    def _deletion_choice(self) -> int:
        """argmin_i |A_i|^2 / (Q_ii + C_ii)  (Csató ogpbvmin.m, summed over outputs)."""
        n = self.n
        a = self._A[:n, : self.d_y]  # the centred columns (not a1)
        den = (_packed.diagonal(self._Qp, self._alloc, n)
               + _packed.diagonal(self._Cp, self._alloc, n))
        # Q_ii + C_ii > 0 in exact arithmetic (a diagonal of K^-1 Sigma_post K^-1); guard it
        score = np.einsum("ij,ij->i", a, a) / np.maximum(den, 1e-300)
        return int(np.argmin(score))

    def delete(self, i: int) -> None:
        """Remove basis vector ``i`` with the rank-1 corrections of thesis App. G(g) (§2.7).

        Off the hot path (the fused step deletes at capacity): ``C`` and ``Q`` are unpacked,
        ``i`` is permuted to the end, and the live ``(n-1) x (n-1)`` block is packed back."""
        n = self.n
        self._forget_diagonals()
        j = n - 1
        cmat = _packed.unpack(self._Cp, self._alloc, n)
        qmat = _packed.unpack(self._Qp, self._alloc, n)
        if i != j:  # permute i to the end
            idx = [i, j]
            rev = [j, i]
            for v in (cmat, qmat):
                v[idx] = v[rev]
                v[:, idx] = v[:, rev]
            self._A[idx] = self._A[rev]
            self._B[idx] = self._B[rev]
        a_star = self._A[j].copy()
        c_star = float(cmat[j, j])
        q_star = float(qmat[j, j])
        q_v = qmat[:j, j].copy()
        w = q_v + cmat[:j, j]
        den = q_star + c_star
        inv_den = 1.0 / den if den > 0.0 else 0.0  # broken: Q-only (marginal) removal
        self._A[:j] -= np.outer(w, a_star) * inv_den
        _packed.pack_into(self._Cp, self._alloc, cmat, j)
        _packed.pack_into(self._Qp, self._alloc, qmat, j)
        cols = np.stack([q_v, w])
        _jit.packed_add_lowrank(self._Cp, self._alloc, j, cols,
                                np.array([1.0 / q_star, -inv_den]))
        _jit.packed_add_lowrank(self._Qp, self._alloc, j, cols[:1], np.array([-1.0 / q_star]))
        self.n = j

    # -- the rest of a step whose steps 3-5 ran batched (:mod:`.sogp_batch`) -------------------

    @property
    def buffers(self) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """``(B, A, C, Q)``: this expert's buffers as views of its slab (``C`` and ``Q``
        packed), as the compiled kernels take them (:mod:`.engine.experts`)."""
        return self._B, self._A, self._Cp, self._Qp

    def finish_kept(self, y: FloatArray, terms: tuple[FloatArray, FloatArray, FloatArray, float],
                    e_hat: FloatArray, gamma: float, margin: float) -> None:
        """Learning ``y`` after a batched novelty test found the point not novel
        (:data:`.engine.jit.KEPT`, ``Q k = e_hat``, residual ``gamma``, test margin
        ``margin``): the projection update (step 4a), the clean-up, the prior mean moved.
        Unlike :meth:`update`, ``Q`` is not re-inverted: step 4a leaves it unchanged."""
        self.novelty_margin = margin
        self.n_points += 1
        k, ck, mean, latent = terms
        y_ext, mean = self.targets(y, mean, k)
        s0 = self.noise
        self._sparse_update(ck, e_hat, gamma, -1.0 / (s0 + latent),
                            (y_ext - mean) / (s0 + latent))
        self._clean_up()
        self._shift_mean(y)

    def finish_fused(self, y: FloatArray, diag: FloatArray, dq: FloatArray, dq_min: float,
                     dq_argmax: int, clean: bool, gamma: float, margin: float) -> None:
        """Learning ``y`` after a batched fused step (:data:`.engine.jit.FUSED`; its returned
        ``diag(C) + diag(Q)``, ``diag(Q)`` with its minimum and first argmax, whether the
        clean-up keeps every basis vector, the residual ``gamma`` and the test margin): the
        diagonals kept, the clean-up where one is due, ``Q`` re-inverted after a
        near-dependent basis vector, the prior mean moved."""
        self.novelty_margin = margin
        self.n_points += 1
        self._dg, self._dq = diag, dq
        self._dq_min, self._dq_argmax = dq_min, dq_argmax
        if not (clean and self.n == self.capacity):
            self._clean_up()
        if gamma < NEAR_DEPENDENT * self.kernel.k_star and self.n > 1:
            self.refresh_inverse_gram()  # a 1/gamma-sized rank-1 term just entered Q
        self._shift_mean(y)

    def _grow(self, need: int) -> None:
        alloc = self._alloc
        if need <= alloc:
            return
        new = max(8, (alloc * 3) // 2)
        if self.capacity is not None:
            new = min(new, self.capacity)
        new = max(new, need)
        old = self.slab
        self._bind(self._new_slab(new), new)
        _jit.grow_slab(old, self.slab, self.n)  # every part moved, C and Q row by row

    def _new_slab(self, alloc: int) -> FloatArray:
        """A zeroed slab for ``alloc`` basis vectors (:func:`.engine.jit_slab.new_slab`)."""
        return jit_slab.new_slab(alloc, self.d_x, self.a_cols, self.d_y)

    def _bind(self, slab: FloatArray, alloc: int) -> None:
        """Take ``slab``, laid out for ``alloc`` basis vectors, as this expert's buffers:
        ``_Cp``, ``_Qp``, ``_B``, ``_A`` and ``_m`` become views of it, its header is written
        (:func:`.engine.jit_slab.bind`; the batched kernels take the slab,
        :mod:`.engine.jit_batch`)."""
        self.slab = slab
        self._alloc = alloc
        self._Cp, self._Qp, self._B, self._A, self._m = jit_slab.bind(
            slab, alloc, self.d_x, self.a_cols, self.d_y)
