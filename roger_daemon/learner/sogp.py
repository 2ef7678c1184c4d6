"""Sparse online Gaussian process (Csató & Opper 2002), the regressor inside every expert.

Multi-output: the ``d_y`` outputs are independent GPs with the same kernel and noise, so they
share the covariance coefficients ``C`` and the inverse Gram matrix ``Q`` (roger-math.md §2.2):

* mean ``f(x) = A^T k_x``, latent variance ``k* + k_x^T C k_x`` (clamped at 1e-12);
* predictive variance of ``y``: ``s0^2 + k* + k_x^T C k_x`` (noise added exactly once, pitfall 4).

Learning one pair is Csató's thesis eq. 2.46 with the KL projection of App. G (roger-math.md
§2.5); capacity ``beta`` is enforced by a ``while n > beta`` loop of KL-optimal deletions
(thesis App. G(g), §2.7), followed by the geometric clean-up.  Every update is a symmetric
low-rank term, so ``C`` and ``Q`` stay symmetric up to round-off (Csató's ``(C + C^T)/2`` is
not needed; the tests check it).

Prior mean (``prior_mean=True``, issue 13): the GP models ``y - m`` where ``m`` is the running
mean of the outputs learned so far, so far from its data the expert predicts ``m`` instead of 0.
The SOGP's coefficients are linear in the targets, so one extra column of ``A`` (``a1``, the
coefficients for the constant target 1) is carried along: when ``m`` moves by ``dm`` after a
point, ``A <- A - a1 dm^T`` makes ``A`` exactly the coefficients of the targets ``y_i - m`` for
the new ``m`` (docs/learner-math.md).  The variance does not involve the targets and is
unchanged; deletion scores use the centred columns only.

Hot path: with continuous data nearly every point is novel, so a full expert does "add a basis
vector, then delete one" at every step.  That pair is fused into one rank-3 update of ``C`` and
one rank-2 update of ``Q``, done in place by BLAS on the contiguous ``beta x beta`` buffer
(:func:`_fused_add_delete`, batched over experts by :func:`update_many`).  Buffers grow by
1.5x as an expert does, up to ``beta`` rows.  Cost per step: O(n d_x + n^2 + n d_y).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt
from scipy.linalg import cho_factor, cho_solve
from scipy.linalg.blas import dgemm as _dgemm

from roger_daemon.learner.kernel import RBFKernel

__all__ = ["LATENT_FLOOR", "SparseOnlineGP", "gaussian_log_likelihood", "update_many"]

FloatArray = npt.NDArray[np.float64]

LATENT_FLOOR = 1e-12  # clamp of k* + k^T C k (Grollman, OTL, Csató)
_GAMMA_FLOOR = 1e-12  # projection residuals below this count as 0 (roger-math.md §2.5 step 3)
_LOG_2PI = math.log(2.0 * math.pi)
# Q = K_B^-1 is kept by rank-1 updates and drifts when K_B is ill-conditioned (pitfall 6: a
# broad kernel and a small novelty threshold admit near-duplicate basis vectors). Two O(n)
# consistency checks that exact arithmetic guarantees trigger a re-inversion from the basis:
# gamma = k* - k^T Q k >= 0 (a squared distance), and Q_ii >= 1/K_ii = 1/k*.
_Q_DRIFT_TOL = 1e-6
_NEAR_DEPENDENT = 1e-3  # a basis vector added with gamma below this (x k*) re-inverts Q
_Q_JITTER = 1e-10  # times k*: first jitter tried if K_B's Cholesky factorisation fails


def _add_lowrank(buf: FloatArray, n: int, cols: FloatArray, coefs: FloatArray) -> None:
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


def gaussian_log_likelihood(sq_err: FloatArray | float, var: FloatArray | float, d_y: int,
                            normaliser: str = "multivariate") -> FloatArray:
    """``log N(y; mu, var * I)`` from ``|y - mu|^2`` and the scalar variance (§2.4).

    ``normaliser="grollman"`` uses the 1-D constant of Grollman's ``SOGP::log_prob``
    (fidelity switch 2): ``-log sqrt(2 pi) - log sigma - |y - mu|^2 / (2 sigma^2)``.
    """
    var = np.asarray(var, dtype=np.float64)
    dims = d_y if normaliser == "multivariate" else 1
    return np.asarray(-0.5 * dims * (_LOG_2PI + np.log(var)) - 0.5 * np.asarray(sq_err) / var)


class SparseOnlineGP:
    """One sparse online GP with ``d_y`` outputs sharing ``C`` and ``Q``.

    Parameters
    ----------
    d_x, d_y : int
        Input and output dimensions.
    kernel : RBFKernel
        Shared kernel (unit amplitude, ``k* = 1``).
    noise : float
        Observation-noise variance ``s0^2`` (``theta_n``).
    capacity : int or None
        Maximum number of basis vectors ``beta``; ``None`` means unbounded.
    novelty_threshold : float
        Full update iff ``gamma >= novelty_threshold * k*`` (and ``gamma > 1e-12``); geometric
        clean-up when ``1/Q_ii < novelty_threshold / 1000``.
    normaliser : {"multivariate", "grollman"}
        Normaliser of :meth:`log_likelihood`.
    prior_mean : bool
        GP prior mean = running mean of the learned outputs (default ``False``: zero mean).

    Examples
    --------
    >>> gp = SparseOnlineGP(1, 1, RBFKernel(0.5, 1), noise=0.01, capacity=20)
    >>> for x in np.linspace(0, 1, 30):
    ...     gp.update(np.array([x]), np.array([np.sin(3 * x)]))
    >>> mean, var = gp.predict(np.array([0.5]))
    >>> bool(abs(mean[0] - np.sin(1.5)) < 0.05), gp.n <= 20
    (True, True)
    """

    __slots__ = ("d_x", "d_y", "kernel", "noise", "capacity", "novelty_threshold", "normaliser",
                 "fused", "n", "n_points", "_B", "_A", "_C", "_Q", "_dg", "q_refreshes",
                 "prior_mean", "_m")

    def __init__(self, d_x: int, d_y: int, kernel: RBFKernel, noise: float,
                 capacity: int | None, novelty_threshold: float = 1e-6,
                 normaliser: str = "multivariate", *, prior_mean: bool = False,
                 _alloc: int | None = None) -> None:
        self.d_x = d_x
        self.d_y = d_y
        self.kernel = kernel
        self.noise = float(noise)
        self.capacity = capacity
        self.novelty_threshold = float(novelty_threshold)
        self.normaliser = normaliser
        self.prior_mean = bool(prior_mean)
        self._m: FloatArray = np.zeros(d_y)  # the prior mean (stays 0 unless prior_mean)
        self.fused = True  # full update + deletion in one pass at capacity (tests switch it)
        self.n = 0  # basis vectors
        self.n_points = 0  # pairs learned
        alloc = _alloc if _alloc is not None else self._initial_alloc()
        self._B: FloatArray = np.zeros((alloc, d_x))
        self._A: FloatArray = np.zeros((alloc, self.a_cols))
        self._C: FloatArray = np.zeros((alloc, alloc))
        self._Q: FloatArray = np.zeros((alloc, alloc))
        self._dg: FloatArray | None = None  # cache of diag(C) + diag(Q), hot path only
        self.q_refreshes = 0  # re-inversions of Q after detected drift

    @property
    def a_cols(self) -> int:
        """Columns of the coefficient buffer: ``d_y``, plus ``a1`` with a prior mean."""
        return self.d_y + 1 if self.prior_mean else self.d_y

    def _initial_alloc(self) -> int:
        return 8 if self.capacity is None else min(8, self.capacity)

    # -- views of the live part ---------------------------------------------------------------

    @property
    def B(self) -> FloatArray:  # noqa: N802 - the thesis' name
        """Basis-vector inputs (n, d_x)."""
        return self._B[: self.n]

    @property
    def A(self) -> FloatArray:  # noqa: N802
        """Mean coefficients alpha (n, d_y), one column per output (of ``y - m``)."""
        return self._A[: self.n, : self.d_y]

    @property
    def mean_offset(self) -> FloatArray:
        """The GP prior mean ``m`` (d_y,): zeros, or the running mean with ``prior_mean``."""
        return self._m.copy()

    @property
    def C(self) -> FloatArray:  # noqa: N802
        """Covariance coefficients (n, n), symmetric, negative-definite-ish."""
        return self._C[: self.n, : self.n]

    @property
    def Q(self) -> FloatArray:  # noqa: N802
        """Inverse Gram matrix ``K_B^{-1}`` (n, n)."""
        return self._Q[: self.n, : self.n]

    # -- prediction ------------------------------------------------------------------------------

    def terms(self, x: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, float]:
        """``(k_x, C k_x, mean, latent variance)``; reused by :meth:`update` (§2.4)."""
        n = self.n
        if n == 0:
            empty = np.zeros(0)
            return empty, empty, self._m.copy(), self.kernel.k_star
        k = self.kernel(self._B[:n], x)
        ck = self._C[:n, :n] @ k
        latent = max(self.kernel.k_star + float(k @ ck), LATENT_FLOOR)
        if not self.prior_mean:
            return k, ck, k @ self._A[:n], latent
        return k, ck, k @ self._A[:n, : self.d_y] + self._m, latent

    def _targets(self, y: FloatArray, mean: FloatArray, k: FloatArray
                 ) -> tuple[FloatArray, FloatArray]:
        """``(y, mean)`` extended by the ``a1`` column (target 1, prediction ``a1^T k``).

        ``y - mean`` is then the residual of every column of ``A``: with a prior mean the
        columns model ``y - m`` and predict ``mean - m``, whose difference is ``y - mean``.
        """
        if not self.prior_mean:
            return y, mean
        a1k = float(k @ self._A[: self.n, self.d_y]) if self.n else 0.0
        return np.append(y, 1.0), np.append(mean, a1k)

    def _shift_mean(self, y: FloatArray) -> None:
        """After learning ``y``: move ``m`` to the new running mean, ``A <- A - a1 dm^T``."""
        if not self.prior_mean:
            return
        dm = (y - self._m) / self.n_points
        self._m = self._m + dm
        n = self.n
        self._A[:n, : self.d_y] -= np.outer(self._A[:n, self.d_y], dm)

    def predict(self, x: FloatArray) -> tuple[FloatArray, float]:
        """Predictive mean (d_y,) and variance of y (scalar, shared by the outputs)."""
        _, _, mean, latent = self.terms(x)
        return mean, self.noise + latent

    def log_likelihood(self, x: FloatArray, y: FloatArray) -> float:
        """``log p(y | x)`` under the predictive Gaussian (§2.4)."""
        mean, var = self.predict(x)
        diff = y - mean
        return float(gaussian_log_likelihood(float(diff @ diff), var, self.d_y, self.normaliser))

    # -- learning ----------------------------------------------------------------------------------

    def update(self, x: FloatArray, y: FloatArray,
               terms: tuple[FloatArray, FloatArray, FloatArray, float] | None = None) -> None:
        """Learn one pair (Csató thesis eq. 2.46, App. G; roger-math.md §2.5).

        ``terms`` may pass :meth:`terms` ``(x)`` computed earlier for this very state.
        """
        self.n_points += 1
        n = self.n
        kstar = self.kernel.k_star
        s0 = self.noise
        self._dg = None  # the fused path below recomputes it
        if n == 0:  # first point, §2.5
            self._B[0] = x
            if self.prior_mean:  # targets [y - m, 1]
                self._A[0, : self.d_y] = (y - self._m) / (kstar + s0)
                self._A[0, self.d_y] = 1.0 / (kstar + s0)
            else:
                self._A[0] = y / (kstar + s0)
            self._C[0, 0] = -1.0 / (kstar + s0)
            self._Q[0, 0] = 1.0 / kstar
            self.n = 1
            self._shift_mean(y)
            return
        k, ck, mean, latent = terms if terms is not None else self.terms(x)
        y, mean = self._targets(y, mean, k)
        # step 2: Gaussian-likelihood scalars (Csató's K2 = r and K1 = q)
        r = -1.0 / (s0 + latent)
        q = (y - mean) / (s0 + latent)
        # step 3: novelty, the projection residual gamma = k* - k^T Q k
        e_hat = self._Q[:n, :n] @ k
        gamma = kstar - float(k @ e_hat)
        if self.q_inconsistent(gamma):
            self.refresh_inverse_gram()
            e_hat = self._Q[:n, :n] @ k
            gamma = kstar - float(k @ e_hat)
        if gamma < _GAMMA_FLOOR:
            gamma = 0.0
        if gamma < self.novelty_threshold * kstar or gamma <= 0.0:
            self._sparse_update(ck, e_hat, gamma, r, q)  # step 4a
        elif self._fusable():
            # steps 4b + 5 fused: add x, then delete the KL-optimal BV, in one pass per matrix
            _fused_add_delete([self], x, y, k[None], ck[None], mean[None], np.array([latent]),
                              e_hat[None], np.array([gamma]))
        else:
            self._full_update(x, ck, e_hat, gamma, r, q)  # step 4b
        self._clean_up()  # steps 5 and 6
        if 0.0 < gamma < _NEAR_DEPENDENT * kstar and self.n > 1:
            self.refresh_inverse_gram()  # a 1/gamma-sized rank-1 term just entered Q
        self._shift_mean(y[: self.d_y])

    def q_inconsistent(self, gamma: float) -> bool:
        """True when ``Q`` has visibly drifted from ``K_B^-1`` (see ``_Q_DRIFT_TOL``)."""
        kstar = self.kernel.k_star
        if gamma < -_Q_DRIFT_TOL * kstar:
            return True
        diag = np.diagonal(self._Q)[: self.n]
        return bool(diag.size and float(diag.min()) * kstar < 1.0 - _Q_DRIFT_TOL)

    def refresh_inverse_gram(self) -> None:
        """Re-invert ``Q = K_B^-1`` from the basis vectors by Cholesky (roger-math.md pitfall 6).

        Only ``Q`` is a function of the basis alone; ``A`` and ``C`` carry the data and are kept.
        Counted in :attr:`q_refreshes`.
        """
        n = self.n
        basis = self._B[:n]
        gram = self.kernel.gram(basis, basis)
        jitter = 0.0
        while True:  # K_B is SPD in exact arithmetic; add jitter only if round-off says no
            try:
                factor = cho_factor(gram + jitter * np.eye(n), lower=True)
                break
            except np.linalg.LinAlgError:
                jitter = max(10.0 * jitter, _Q_JITTER * self.kernel.k_star)
        inv = cho_solve(factor, np.eye(n))
        self._Q[:n, :n] = 0.5 * (inv + inv.T)
        self._dg = None
        self.q_refreshes += 1

    def _diag_cq(self) -> FloatArray:
        """``diag(C) + diag(Q)`` (cached by the fused hot path, else read off the matrices)."""
        if self._dg is not None:
            return self._dg
        n = self.n
        return np.diagonal(self._C)[:n] + np.diagonal(self._Q)[:n]

    def _fusable(self) -> bool:
        """Full and contiguous: the fused add-then-delete hot path applies."""
        return (self.fused and self.capacity is not None and self.n == self.capacity
                and self._C.shape[0] == self.n)

    def _sparse_update(self, ck: FloatArray, e_hat: FloatArray, gamma: float, r: float,
                       q: FloatArray) -> None:
        """Step 4a: projection update, BV set unchanged; ``eta = 1/(1 + gamma r)``."""
        n = self.n
        self._dg = None
        eta = 1.0 / (1.0 + gamma * r)
        s_hat = ck + e_hat
        self._A[:n] += np.outer(s_hat, q) * eta
        _add_lowrank(self._C, n, s_hat[:, None], np.array([r * eta]))

    def _clean_up(self) -> None:
        """Steps 5 and 6: ``while n > beta`` delete; geometric clean-up (Csató)."""
        if self.capacity is not None:
            while self.n > self.capacity:
                self.delete(self._deletion_choice())
        floor = self.novelty_threshold * 1e-3
        while self.n > 1 and floor > 0.0:
            diag = np.diagonal(self._Q)[: self.n]
            i = int(np.argmax(diag))
            if 1.0 / diag[i] >= floor:
                break
            self.delete(i)

    def _full_update(self, x: FloatArray, ck: FloatArray, e_hat: FloatArray, gamma: float,
                     r: float, q: FloatArray) -> None:
        """Step 4b: x becomes basis vector n (thesis eq. 2.46; Q by eq. 3.5)."""
        n = self.n
        self._dg = None
        self._grow(n + 1)
        self._B[n] = x
        s = np.empty(n + 1)
        s[:n] = ck
        s[n] = 1.0
        self._A[n] = 0.0
        self._A[: n + 1] += np.outer(s, q)
        e = np.empty(n + 1)
        e[:n] = e_hat
        e[n] = -1.0
        for mat in (self._C, self._Q):
            mat[n, : n + 1] = 0.0
            mat[:n, n] = 0.0
        _add_lowrank(self._C, n + 1, s[:, None], np.array([r]))
        _add_lowrank(self._Q, n + 1, e[:, None], np.array([1.0 / gamma]))
        self.n = n + 1

    def _deletion_choice(self) -> int:
        """argmin_i |A_i|^2 / (Q_ii + C_ii)  (Csató ogpbvmin.m, summed over outputs)."""
        n = self.n
        a = self._A[:n, : self.d_y]  # the centred columns (not a1)
        den = np.diagonal(self._Q)[:n] + np.diagonal(self._C)[:n]
        # Q_ii + C_ii > 0 in exact arithmetic (a diagonal of K^-1 Sigma_post K^-1); guard it
        score = np.einsum("ij,ij->i", a, a) / np.maximum(den, 1e-300)
        return int(np.argmin(score))

    def delete(self, i: int) -> None:
        """Remove basis vector ``i`` with the rank-1 corrections of thesis App. G(g) (§2.7)."""
        n = self.n
        self._dg = None
        j = n - 1
        if i != j:  # permute i to the end
            idx = [i, j]
            rev = [j, i]
            for mat in (self._C, self._Q):
                v = mat[:n, :n]
                v[idx] = v[rev]
                v[:, idx] = v[:, rev]
            self._A[idx] = self._A[rev]
            self._B[idx] = self._B[rev]
        a_star = self._A[j].copy()
        c_star = float(self._C[j, j])
        q_star = float(self._Q[j, j])
        q_v = self._Q[:j, j].copy()
        w = q_v + self._C[:j, j]
        den = q_star + c_star
        inv_den = 1.0 / den if den > 0.0 else 0.0  # broken: Q-only (marginal) removal
        self._A[:j] -= np.outer(w, a_star) * inv_den
        cols = np.empty((j, 2), order="F")
        cols[:, 0] = q_v
        cols[:, 1] = w
        _add_lowrank(self._C, j, cols, np.array([1.0 / q_star, -inv_den]))
        _add_lowrank(self._Q, j, cols[:, :1], np.array([-1.0 / q_star]))
        self.n = j

    def _grow(self, need: int) -> None:
        alloc = self._C.shape[0]
        if need <= alloc:
            return
        new = max(8, (alloc * 3) // 2)
        if self.capacity is not None:
            new = min(new, self.capacity)
        new = max(new, need)
        n = self.n
        for name in ("_B", "_A"):
            old = getattr(self, name)
            buf = np.zeros((new, old.shape[1]))
            buf[:n] = old[:n]
            setattr(self, name, buf)
        for name in ("_C", "_Q"):
            old = getattr(self, name)
            buf = np.zeros((new, new))
            buf[:n, :n] = old[:n, :n]
            setattr(self, name, buf)

    # -- copies and state ----------------------------------------------------------------------

    def copy(self) -> SparseOnlineGP:
        """An independent copy (used for copy-on-write in :class:`~.roger.Roger`)."""
        out = SparseOnlineGP(self.d_x, self.d_y, self.kernel, self.noise, self.capacity,
                             self.novelty_threshold, self.normaliser,
                             prior_mean=self.prior_mean, _alloc=0)
        out._m = self._m.copy()
        out.fused = self.fused
        out.n = self.n
        out.n_points = self.n_points
        # whole buffers: one memcpy each (the padding is never read)
        out._B = self._B.copy()
        out._A = self._A.copy()
        out._C = self._C.copy()
        out._Q = self._Q.copy()
        out._dg = None if self._dg is None else self._dg.copy()
        out.q_refreshes = self.q_refreshes
        return out

    def load(self, B: FloatArray, A: FloatArray, C: FloatArray, Q: FloatArray,  # noqa: N803
             n_points: int, alloc: int | None = None, diag_cache: FloatArray | None = None,
             mean: FloatArray | None = None) -> None:
        """Set the state from arrays (inverse of reading :attr:`B`, :attr:`A`, :attr:`C`, ...).

        ``A`` has :attr:`a_cols` columns (``a1`` last with a prior mean); ``mean`` is
        :attr:`mean_offset`.  ``alloc`` restores the buffer size too, so that a restored expert
        computes with the same memory layout as the saved one.
        """
        n = B.shape[0]
        self.n = 0
        self._dg = None
        size = max(n, self._C.shape[0] if alloc is None else int(alloc))
        if size != self._C.shape[0]:
            self._B = np.zeros((size, self.d_x))
            self._A = np.zeros((size, self.a_cols))
            self._C = np.zeros((size, size))
            self._Q = np.zeros((size, size))
        self._B[:n] = B
        self._A[:n] = A
        self._C[:n, :n] = C
        self._Q[:n, :n] = Q
        self.n = n
        self.n_points = int(n_points)
        self._m = np.zeros(self.d_y) if mean is None else np.array(mean, dtype=np.float64)
        self._dg = None if diag_cache is None else np.array(diag_cache, dtype=np.float64)


Terms = tuple[FloatArray, FloatArray, FloatArray, float]


def update_many(gps: Sequence[SparseOnlineGP], x: FloatArray, y: FloatArray,
                terms: Sequence[Terms | None]) -> None:
    """Learn the same pair in several distinct experts (one ROGER step's chosen experts).

    Equivalent to ``gp.update(x, y, t)`` for each, but the experts on the hot path (full,
    contiguous, ``x`` novel) share one batched evaluation of the fused add-then-delete step,
    so the per-expert Python work is a handful of in-place BLAS calls.
    """
    full: list[SparseOnlineGP] = []
    full_terms: list[Terms] = []
    for gp, t in zip(gps, terms, strict=True):
        if gp._fusable():
            full.append(gp)
            full_terms.append(t if t is not None else gp.terms(x))
        else:
            gp.update(x, y, t)
    if not full:
        return
    y_pub = y
    kstar = full[0].kernel.k_star
    ks = np.stack([t[0] for t in full_terms])
    cks = np.stack([t[1] for t in full_terms])
    means = np.stack([t[2] for t in full_terms])
    if full[0].prior_mean:  # extend by the a1 column: target 1, prediction a1^T k (one model)
        y = np.append(y, 1.0)
        a1k = np.array([float(k @ gp._A[:, gp.d_y]) for gp, k in zip(full, ks, strict=True)])
        means = np.concatenate([means, a1k[:, None]], axis=1)
    latents = np.array([t[3] for t in full_terms])
    e_hat = np.stack([gp._Q @ k for gp, k in zip(full, ks, strict=True)])  # step 3: Q k
    gamma = kstar - np.einsum("un,un->u", ks, e_hat)
    for j, gp in enumerate(full):
        if gp.q_inconsistent(float(gamma[j])):
            gp.refresh_inverse_gram()
            e_hat[j] = gp._Q @ ks[j]
            gamma[j] = kstar - float(ks[j] @ e_hat[j])
    gamma[gamma < _GAMMA_FLOOR] = 0.0
    novel = (gamma >= np.array([g.novelty_threshold for g in full]) * kstar) & (gamma > 0.0)
    if not np.all(novel):
        for j in np.flatnonzero(~novel).tolist():  # step 4a for the non-novel few
            gp = full[j]
            gp.n_points += 1
            s0 = gp.noise
            gp._sparse_update(cks[j], e_hat[j], float(gamma[j]), -1.0 / (s0 + latents[j]),
                              (y - means[j]) / (s0 + latents[j]))
            gp._clean_up()
            gp._shift_mean(y_pub)
        keep = np.flatnonzero(novel)
        full = [full[j] for j in keep.tolist()]
        if not full:
            return
        ks, cks, means, latents = ks[keep], cks[keep], means[keep], latents[keep]
        e_hat, gamma = e_hat[keep], gamma[keep]
    for gp in full:
        gp.n_points += 1
    _fused_add_delete(full, x, y, ks, cks, means, latents, e_hat, gamma)
    for gp, g in zip(full, gamma.tolist(), strict=True):
        gp._clean_up()
        if g < _NEAR_DEPENDENT * kstar and gp.n > 1:
            gp.refresh_inverse_gram()  # a 1/gamma-sized rank-1 term just entered Q
        gp._shift_mean(y_pub)


def _fused_add_delete(gps: Sequence[SparseOnlineGP], x: FloatArray, y: FloatArray,
                      ks: FloatArray, cks: FloatArray, means: FloatArray, latents: FloatArray,
                      e_hat: FloatArray, gamma: FloatArray) -> None:
    """Full update to n + 1 BVs then one KL-optimal deletion, for u full experts at once.

    With ``s = [Ck; 1]`` and ``e = [Q k; -1]`` the (n+1)-BV state would be
    ``C1 = C (+) 0 + r s s^T``, ``Q1 = Q (+) 0 + e e^T / gamma``, ``A1 = A (+) 0 + s q^T``
    (roger-math.md §2.5 step 4b).  Deleting BV ``i`` (§2.7) needs only column ``i`` and the
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
        if old[j]:
            i = int(idx[j])
            for mat in (gp._C, gp._Q):
                mat[i, :] = 0.0
                mat[:, i] = 0.0
            gp._B[i] = x
        gp._A[:n] = a_stack[j]
        _add_lowrank(gp._C, n, cols_c[j].T, coef_c[j])
        _add_lowrank(gp._Q, n, cols_q[j].T, coef_q[j])
        gp._dg = diag[j].copy()
