"""Sparse online Gaussian process (Csató & Opper 2002), the regressor inside every expert.

Multi-output: the ``d_y`` outputs are independent GPs with the same kernel and noise, so they
share the covariance coefficients ``C`` and the inverse Gram matrix ``Q``
(docs/learner-math.md §2.2):

* mean ``f(x) = A^T k_x``, latent variance ``k* + k_x^T C k_x`` (clamped at 1e-12);
* predictive variance of ``y``: ``s0^2 + k* + k_x^T C k_x`` (noise added exactly once, pitfall 4).

Learning one pair is Csató's thesis eq. 2.46 with the KL projection of App. G (docs/learner-math.md
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
(:mod:`.sogp_fused`, batched over experts by :func:`update_many`).  Buffers grow by
1.5x as an expert does, up to ``beta`` rows.  Cost per step: O(n d_x + n^2 + n d_y).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt
from scipy.linalg.lapack import dpotrf as _dpotrf
from scipy.linalg.lapack import dpotri as _dpotri

from roger_daemon.learner import jit as _jit
from roger_daemon.learner.kernel import RBFKernel
from roger_daemon.learner.sogp_fused import add_lowrank as _add_lowrank
from roger_daemon.learner.sogp_fused import fused_add_delete as _fused_add_delete

__all__ = ["LATENT_FLOOR", "SparseOnlineGP", "gaussian_log_likelihood", "update_many"]

FloatArray = npt.NDArray[np.float64]

LATENT_FLOOR = 1e-12  # clamp of k* + k^T C k (Grollman, OTL, Csató)
_GAMMA_FLOOR = 1e-12  # projection residuals below this count as 0 (learner-math.md §2.5 step 3)
_LOG_2PI = math.log(2.0 * math.pi)
# Q = K_B^-1 is kept by rank-1 updates and drifts when K_B is ill-conditioned (pitfall 6: a
# broad kernel and a small novelty threshold admit near-duplicate basis vectors). Two O(n)
# consistency checks that exact arithmetic guarantees trigger a re-inversion from the basis:
# gamma = k* - k^T Q k >= 0 (a squared distance), and Q_ii >= 1/K_ii = 1/k*.
_Q_DRIFT_TOL = 1e-6
_NEAR_DEPENDENT = 1e-3  # a basis vector added with gamma below this (x k*) re-inverts Q
_Q_JITTER = 1e-10  # times k*: first jitter tried if K_B's Cholesky factorisation fails


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
                 "fused", "n", "n_points", "_B", "_A", "_C", "_Q", "_K", "_dg", "q_refreshes",
                 "prior_mean", "_m", "novelty_margin")

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
        # K_B, kept alongside Q (its rows are the kernel vectors already computed when each
        # basis vector entered), so a re-inversion of Q costs a Cholesky, not a Gram matrix
        self._K: FloatArray = np.zeros((alloc, alloc))
        self._dg: FloatArray | None = None  # cache of diag(C) + diag(Q), hot path only
        self.q_refreshes = 0  # re-inversions of Q after detected drift
        # |gamma - threshold k*| / k* of the last update's novelty test (diagnostic, not state;
        # docs/reproducibility.md): how close that discrete decision was to going the other way
        self.novelty_margin = math.inf

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
        if n <= _jit.SMALL:  # one compiled call: kernel, C k, k^T C k, k^T A
            packed = _jit.expert_terms(self._B, self._C, self._A, x, self.kernel.gamma, n)
            k, ck, mean = packed[:n], packed[n: 2 * n], packed[2 * n + 1:]
            kck = float(packed[2 * n])
        else:  # C k by BLAS
            k = _jit.kernel_vector(self._B, x, self.kernel.gamma, n)
            ck = self._C[:n, :n] @ k
            kck = float(k @ ck)
            mean = k @ self._A[:n]
        latent = max(self.kernel.k_star + kck, LATENT_FLOOR)
        if not self.prior_mean:
            return k, ck, mean, latent
        return k, ck, mean[: self.d_y] + self._m, latent

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
        """Learn one pair (Csató thesis eq. 2.46, App. G; docs/learner-math.md §2.5).

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
            self._K[0, 0] = kstar
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
        self.novelty_margin = abs(gamma - self.novelty_threshold * kstar) / kstar
        if gamma < self.novelty_threshold * kstar or gamma <= 0.0:
            self._sparse_update(ck, e_hat, gamma, r, q)  # step 4a
        elif self._fusable():
            # steps 4b + 5 fused: add x, then delete the KL-optimal BV, in one pass per matrix
            _fused_add_delete([self], x, y, k[None], ck[None], mean[None], np.array([latent]),
                              e_hat[None], np.array([gamma]))
        else:
            self._full_update(x, k, ck, e_hat, gamma, r, q)  # step 4b
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
        """Re-invert ``Q = K_B^-1`` by Cholesky (docs/learner-math.md, matrix drift).

        Only ``Q`` is a function of the basis alone; ``A`` and ``C`` carry the data and are kept.
        ``K_B`` is the kept copy (no Gram matrix is recomputed); LAPACK ``dpotrf`` then
        ``dpotri`` (the inverse from the factor, lower triangle mirrored, so ``Q`` is exactly
        symmetric).  Counted in :attr:`q_refreshes`.
        """
        n = self.n
        jitter = 0.0
        if n <= _jit.SMALL:  # compiled: no LAPACK call overhead at this size
            while not _jit.cholesky_inverse(self._K, n, jitter, self._Q):
                jitter = max(10.0 * jitter, _Q_JITTER * self.kernel.k_star)
            self._dg = None
            self.q_refreshes += 1
            return
        gram = self._K[:n, :n]
        while True:  # K_B is SPD in exact arithmetic; add jitter only if round-off says no
            factor, info = _dpotrf(gram if jitter == 0.0 else gram + jitter * np.eye(n),
                                   lower=1, clean=0)
            if info == 0:
                break
            jitter = max(10.0 * jitter, _Q_JITTER * self.kernel.k_star)
        inv, _ = _dpotri(factor, lower=1, overwrite_c=1)
        low = np.tril(inv)
        self._Q[:n, :n] = low + np.tril(low, -1).T
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

    def _full_update(self, x: FloatArray, k: FloatArray, ck: FloatArray, e_hat: FloatArray,
                     gamma: float, r: float, q: FloatArray) -> None:
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
        self._K[n, :n] = k
        self._K[:n, n] = k
        self._K[n, n] = self.kernel.k_star
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
            for mat in (self._C, self._Q, self._K):
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
        for name in ("_C", "_Q", "_K"):
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
        out._K = self._K.copy()
        out._dg = None if self._dg is None else self._dg.copy()
        out.q_refreshes = self.q_refreshes
        return out

    def load(self, B: FloatArray, A: FloatArray, C: FloatArray, Q: FloatArray,  # noqa: N803
             n_points: int, alloc: int | None = None, diag_cache: FloatArray | None = None,
             mean: FloatArray | None = None, gram: FloatArray | None = None) -> None:
        """Set the state from arrays (inverse of reading :attr:`B`, :attr:`A`, :attr:`C`, ...).

        ``A`` has :attr:`a_cols` columns (``a1`` last with a prior mean); ``mean`` is
        :attr:`mean_offset`, ``gram`` the kept ``K_B`` (recomputed from ``B`` if ``None``).
        ``alloc`` restores the buffer size too, so that a restored expert
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
            self._K = np.zeros((size, size))
        self._B[:n] = B
        self._A[:n] = A
        self._C[:n, :n] = C
        self._Q[:n, :n] = Q
        self._K[:n, :n] = self.kernel.gram(B, B) if gram is None else gram
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
    thresholds = np.array([g.novelty_threshold for g in full]) * kstar
    for gp, m in zip(full, (np.abs(gamma - thresholds) / kstar).tolist(), strict=True):
        gp.novelty_margin = m
    novel = (gamma >= thresholds) & (gamma > 0.0)
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
