"""Sparse online Gaussian process (Csató & Opper 2002), the regressor inside every expert.

Multi-output: the ``d_y`` outputs are independent GPs with the same kernel and noise, so they
share the covariance coefficients ``C`` and the inverse Gram matrix ``Q``
(docs/learner-math.md §2.2):

* mean ``f(x) = A^T k_x``, latent variance ``k* + k_x^T C k_x`` (clamped at 1e-12);
* predictive variance of ``y``: ``s0^2 + k* + k_x^T C k_x`` (noise added exactly once, pitfall 4).

Learning one pair is Csató's thesis eq. 2.46 with the KL projection of App. G (docs/learner-math.md
§2.5); capacity ``beta`` is enforced by a ``while n > beta`` loop of KL-optimal deletions
(thesis App. G(g), §2.7), followed by the geometric clean-up.  Every update is a symmetric
low-rank term and ``C`` and ``Q`` are stored as their upper triangles (:mod:`.engine.packed`), so
they are exactly symmetric (Csató's ``(C + C^T)/2`` is not needed).

Prior mean (``prior_mean=True``, issue 13): the GP models ``y - m`` where ``m`` is the running
mean of the outputs learned so far, so far from its data the expert predicts ``m`` instead of 0.
The SOGP's coefficients are linear in the targets, so one extra column of ``A`` (``a1``, the
coefficients for the constant target 1) is carried along: when ``m`` moves by ``dm`` after a
point, ``A <- A - a1 dm^T`` makes ``A`` exactly the coefficients of the targets ``y_i - m`` for
the new ``m`` (docs/learner-math.md).  The variance does not involve the targets and is
unchanged; deletion scores use the centred columns only.

Hot path: with continuous data nearly every point is novel, so a full expert does "add a basis
vector, then delete one" at every step, fused into one rank-3 update of ``C`` and one rank-2
update of ``Q`` in one compiled pass over each (:mod:`.engine.jit_fused`; several experts per
call by :mod:`.sogp_batch`).  ``C`` and ``Q`` are stored packed, upper triangle only
(:mod:`.engine.packed`): every pass streams half the bytes.  Buffers grow by 1.5x as an expert
does, up to ``beta`` rows.  Cost per step: O(n d_x + n^2 + n d_y).

Modules: this one holds the state, prediction and the update's steps in order; the matrix
steps themselves (updates, deletion, clean-up, re-inversion of ``Q``) are :mod:`.sogp_steps`,
on the engine's compiled kernels (:mod:`.engine`).
"""

from __future__ import annotations

import copy
import math
from typing import Any

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.engine import jit as _jit
from roger_daemon.learner.engine import packed as _packed
from roger_daemon.learner.engine.buffers import BufferPool, PendingCopy
from roger_daemon.learner.kernel import RBFKernel
from roger_daemon.learner.sogp_steps import LATENT_FLOOR, SOGPSteps
from roger_daemon.learner.sogp_steps import NEAR_DEPENDENT as _NEAR_DEPENDENT

__all__ = ["LATENT_FLOOR", "SparseOnlineGP", "gaussian_log_likelihood", "likelihood_dims"]

FloatArray = npt.NDArray[np.float64]


def likelihood_dims(d_y: int, normaliser: str) -> int:
    """The dimensions in the Gaussian's normalising constant: ``d_y``, or 1 with
    ``normaliser="grollman"`` (Grollman's ``SOGP::log_prob``, fidelity switch 2)."""
    return d_y if normaliser == "multivariate" else 1


def gaussian_log_likelihood(sq_err: float, var: float, d_y: int,
                            normaliser: str = "multivariate") -> float:
    """``log N(y; mu, var * I)`` from ``|y - mu|^2`` and the scalar variance (§2.4).

    ``normaliser="grollman"`` uses the 1-D constant of Grollman's ``SOGP::log_prob``
    (fidelity switch 2): ``-log sqrt(2 pi) - log sigma - |y - mu|^2 / (2 sigma^2)``.  The
    compiled density a step's putatives use (:func:`.jit_weights.gaussian_log_density`).
    """
    return float(_jit.gaussian_log_density(float(sq_err), float(var),
                                           likelihood_dims(d_y, normaliser)))


class SparseOnlineGP(SOGPSteps):
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

    __slots__ = ()  # the instance attributes are declared by SOGPSteps

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
        self.home = -1
        self.fused = True  # full update + deletion in one pass at capacity (tests switch it)
        self.n = 0  # basis vectors
        self.n_points = 0  # pairs learned
        # the buffers, views of one slab (:mod:`.jit_slab`): C and Q packed, their upper
        # triangles row by row (:mod:`.packed`); B, A; the prior mean m (0 unless prior_mean)
        alloc = _alloc if _alloc is not None else self._initial_alloc()
        self._bind(self._new_slab(alloc), alloc)
        # K_B is not kept: a re-inversion of Q recomputes it from B, to the same floats as the
        # kernel vectors computed when each basis vector entered (.jit_kernels.gram_matrix)
        self._dg: FloatArray | None = None  # cache of diag(C) + diag(Q), hot path only
        self._dq: FloatArray | None = None  # diag(Q) as stored, from the fused step
        self._dq_min, self._dq_argmax = math.nan, -1
        self.q_refreshes = 0  # re-inversions of Q after detected drift
        # |gamma - threshold k*| / k* of the last update's novelty test (diagnostic, not state;
        # docs/reproducibility.md): how close that discrete decision was to going the other way
        self.novelty_margin = math.inf

    def _initial_alloc(self) -> int:
        return 8 if self.capacity is None else min(8, self.capacity)

    # -- views of the live part ---------------------------------------------------------------

    @property
    def B(self) -> FloatArray:
        """Basis-vector inputs (n, d_x)."""
        return self._B[: self.n]

    @property
    def A(self) -> FloatArray:
        """Mean coefficients alpha (n, d_y), one column per output (of ``y - m``)."""
        return self._A[: self.n, : self.d_y]

    @property
    def mean_offset(self) -> FloatArray:
        """The GP prior mean ``m`` (d_y,): zeros, or the running mean with ``prior_mean``."""
        return self._m.copy()

    @property
    def alloc(self) -> int:
        """Basis vectors the buffers are sized for (``>= n``; ``beta`` once full)."""
        return self._alloc

    @property
    def C(self) -> FloatArray:
        """Covariance coefficients (n, n), symmetric, negative-definite-ish (a copy, unpacked)."""
        return _packed.unpack(self._Cp, self._alloc, self.n)

    @property
    def Q(self) -> FloatArray:
        """Inverse Gram matrix ``K_B^{-1}`` (n, n) (a copy, unpacked)."""
        return _packed.unpack(self._Qp, self._alloc, self.n)

    @property
    def gram(self) -> FloatArray:
        """The Gram matrix ``K_B`` of the basis (n, n), computed from :attr:`B` (the floats a
        re-inversion of ``Q`` uses: :func:`.jit_kernels.gram_matrix`)."""
        return self._gram_matrix()

    # -- prediction ------------------------------------------------------------------------------

    def terms(self, x: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, float]:
        """``(k_x, C k_x, mean, latent variance)``; reused by :meth:`update` (§2.4)."""
        n = self.n
        if n == 0:
            empty = np.zeros(0)
            return empty, empty, self._m.copy(), self.kernel.k_star
        # one compiled call: kernel, C k, k^T C k, k^T A (one pass over C, no BLAS)
        return self.terms_from(_jit.expert_terms(self._B, self._Cp, self._A, x,
                                                  self.kernel.gamma, n, self._alloc))

    def terms_from(self, packed: FloatArray
                    ) -> tuple[FloatArray, FloatArray, FloatArray, float]:
        """:meth:`terms` from the compiled ``[k, C k, k^T C k, k^T A]`` of this expert (one
        call, :func:`.jit_kernels.expert_terms`, or several experts' at once:
        :meth:`.sogp_batch.Evaluation.terms`)."""
        n = self.n
        k, ck, mean = packed[:n], packed[n: 2 * n], packed[2 * n + 1:]
        kck = float(packed[2 * n])
        latent = max(self.kernel.k_star + kck, LATENT_FLOOR)
        if not self.prior_mean:
            return k, ck, mean, latent
        return k, ck, mean[: self.d_y] + self._m, latent

    def predict(self, x: FloatArray) -> tuple[FloatArray, float]:
        """Predictive mean (d_y,) and variance of y (scalar, shared by the outputs)."""
        _, _, mean, latent = self.terms(x)
        return mean, self.noise + latent

    def log_likelihood(self, x: FloatArray, y: FloatArray) -> float:
        """``log p(y | x)`` under the predictive Gaussian (§2.4)."""
        mean, var = self.predict(x)
        diff = y - mean
        return gaussian_log_likelihood(float(diff @ diff), var, self.d_y, self.normaliser)

    # -- learning ----------------------------------------------------------------------------------

    def update(self, x: FloatArray, y: FloatArray,
               terms: tuple[FloatArray, FloatArray, FloatArray, float] | None = None) -> None:
        """Learn one pair (Csató thesis eq. 2.46, App. G; docs/learner-math.md §2.5).

        ``terms`` may pass :meth:`terms` ``(x)`` computed earlier for this very state.  Step 1
        (the first point), step 2 (Csató's scalars), then: an expert with room for another
        basis vector takes steps 3, 4 and step 6's test in one compiled call
        (:func:`.engine.jit_small.growth_step`); a full one (or one whose ``Q`` drifted, or
        whose buffers must grow first) the novelty test (step 3), then the projection update
        (4a), the fused add-then-delete at capacity (4b + 5) or the full update (4b), the
        deletions and the clean-up (5, 6).
        """
        self.n_points += 1
        self._forget_diagonals()  # the fused path below recomputes them
        if self.n == 0:
            self._first_point(x, y)
            return
        k, ck, mean, latent = terms if terms is not None else self.terms(x)
        y, mean = self.targets(y, mean, k)
        # step 2: Gaussian-likelihood scalars (Csató's K2 = r and K1 = q)
        r = -1.0 / (self.noise + latent)
        q = (y - mean) / (self.noise + latent)
        if not self.fusable() and self._grew(x, k, ck, q, r, y):
            return
        e_hat, gamma, novel = self.novelty(k)  # step 3 (Q re-inverted first if it drifted)
        if not novel:
            self._sparse_update(ck, e_hat, gamma, r, q)  # step 4a
        elif self.fusable():
            # steps 4b + 5 fused: add x, then delete the KL-optimal BV, in one pass per matrix
            self._fused_add_delete(x, ck, e_hat, gamma, r, q)
        else:
            self._full_update(x, ck, e_hat, gamma, r, q)  # step 4b
        self._clean_up()  # steps 5 and 6
        self._after_update(gamma, y)

    def _first_point(self, x: FloatArray, y: FloatArray) -> None:
        """Step 1 (§2.5): the first point is the first basis vector."""
        kstar, s0 = self.kernel.k_star, self.noise
        self._B[0] = x
        if self.prior_mean:  # targets [y - m, 1]
            self._A[0, : self.d_y] = (y - self._m) / (kstar + s0)
            self._A[0, self.d_y] = 1.0 / (kstar + s0)
        else:
            self._A[0] = y / (kstar + s0)
        self._Cp[0] = -1.0 / (kstar + s0)  # C[0, 0]: the packed buffer starts with it
        self._Qp[0] = 1.0 / kstar
        self.n = 1
        self._shift_mean(y)

    def _grew(self, x: FloatArray, k: FloatArray, ck: FloatArray, q: FloatArray, r: float,
              y: FloatArray) -> bool:
        """Steps 3, 4 and step 6's test of an expert that is not full, in one compiled call
        (:func:`.engine.jit_small.growth_step`), then the rest of the step; ``False`` (nothing
        changed) where ``Q`` drifted or the buffers must grow first."""
        outcome, gamma, clean = _jit.growth_step(
            self._B, self._A, self._Cp, self._Qp, self._alloc, self.n, x, k, ck, q, r,
            *self.novelty_constants(), self.cleanup_floor())
        if outcome not in (_jit.ADDED, _jit.PROJECTED):
            return False
        self.record_novelty_margin(gamma)
        if outcome == _jit.ADDED:
            self.n += 1
        # step 5 too past beta (buffers for beta + 1 without the fused step)
        if not clean or (self.capacity is not None and self.n > self.capacity):
            self._clean_up()
        self._after_update(gamma, y)
        return True

    def _after_update(self, gamma: float, y: FloatArray) -> None:
        """The end of :meth:`update`: ``Q`` re-inverted after a near-dependent basis vector
        (residual ``gamma``); the prior mean moved towards ``y`` (its first ``d_y`` entries)."""
        if 0.0 < gamma < _NEAR_DEPENDENT * self.kernel.k_star and self.n > 1:
            self.refresh_inverse_gram()  # a 1/gamma-sized rank-1 term just entered Q
        self._shift_mean(y[: self.d_y])

    # -- copies and state ----------------------------------------------------------------------

    def copy(self, pool: BufferPool | None = None,
             pending: list[PendingCopy] | None = None) -> SparseOnlineGP:
        """An independent copy (used for copy-on-write in :class:`~.roger.Roger`); its slab
        (:mod:`.jit_slab`) goes into a buffer kept in ``pool`` when it has one of its size.
        With ``pending`` (and a pool) the slab is copied later, by the caller
        (:meth:`.buffers.BufferPool.copy_of`)."""
        out = SparseOnlineGP(self.d_x, self.d_y, self.kernel, self.noise, self.capacity,
                             self.novelty_threshold, self.normaliser,
                             prior_mean=self.prior_mean, _alloc=0)
        out.fused = self.fused
        out.home = self.home
        out.n = self.n
        out.n_points = self.n_points
        # the whole slab: one memcpy (the padding is never read)
        slab = (self.slab.copy() if pool is None
                else pool.copy_of(self.slab, pending, self.home))
        out._bind(slab, self._alloc)
        out._dg = None if self._dg is None else self._dg.copy()
        out._dq = None if self._dq is None else self._dq.copy()
        out._dq_min, out._dq_argmax = self._dq_min, self._dq_argmax
        out.q_refreshes = self.q_refreshes
        return out

    def __deepcopy__(self, memo: dict[int, Any]) -> SparseOnlineGP:
        """``copy.deepcopy``: :meth:`copy`, whose buffers are views of the copy's own slab (a
        field-by-field deep copy would copy each view apart from the slab the batched kernels
        read, :mod:`.jit_slab`)."""
        out = self.copy()
        out.kernel = copy.deepcopy(self.kernel, memo)
        out.novelty_margin = self.novelty_margin
        memo[id(self)] = out
        return out

    def release(self, pool: BufferPool) -> None:
        """Give this expert's slab to ``pool`` for later copies (the model has dropped it: it
        must not be used afterwards), with its home (:meth:`.buffers.BufferPool.give`)."""
        pool.give(self.slab, self.home)

    def load(self, B: FloatArray, A: FloatArray, C: FloatArray, Q: FloatArray,
             n_points: int, alloc: int | None = None, diag_cache: FloatArray | None = None,
             mean: FloatArray | None = None) -> None:
        """Set the state from arrays (inverse of reading :attr:`B`, :attr:`A`, :attr:`C`, ...).

        ``A`` has :attr:`a_cols` columns (``a1`` last with a prior mean); ``mean`` is
        :attr:`mean_offset`.
        ``alloc`` restores the buffer size too, so that a restored expert
        computes with the same memory layout as the saved one.
        """
        n = B.shape[0]
        self.n = 0
        self._forget_diagonals()
        size = max(n, self._alloc if alloc is None else int(alloc))
        self._bind(self._new_slab(size), size)
        self._B[:n] = B
        self._A[:n] = A
        # the upper triangles (a state from before packed storage may hold a C or Q that is
        # symmetric only to round-off: its upper triangle is taken)
        _packed.pack_into(self._Cp, size, np.asarray(C, dtype=np.float64), n)
        _packed.pack_into(self._Qp, size, np.asarray(Q, dtype=np.float64), n)
        self.n = n
        self.n_points = int(n_points)
        if mean is not None:
            self._m[:] = np.asarray(mean, dtype=np.float64)
        self._dg = None if diag_cache is None else np.array(diag_cache, dtype=np.float64)
