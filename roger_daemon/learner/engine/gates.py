"""The NIW input gates of many experts in stacked arrays, indexed by integer slot
(docs/learner-math.md §3): posterior statistics, cached predictive, batched evaluation.

Each gate is the conjugate NIW posterior over the mean and covariance of the inputs its expert
generated (paper eq. 1; the one-gate view is :class:`roger_daemon.learner.gate.NIWGate`).
Statistics are kept as (kappa, nu, mu, Lambda) and updated with the rank-1 recursion of §3.2,
never as raw sums of x x^T (pitfall 10 of docs/learner-math.md §7).  For evaluation each gate
caches the precision ``Lambda^{-1}``, ``log|Lambda|`` and the log normaliser; a rank-1 update
of Lambda updates them in O(d^2) by Sherman-Morrison and the matrix determinant lemma, and
every 32 updates they are recomputed from Lambda by Cholesky, so round-off cannot accumulate
(:func:`.jit_particles.gate_update`).  ``log t(x)`` then costs one matrix-vector product; the
pool evaluates many gates in one compiled call (§3.4).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.engine import jit as _jit
from roger_daemon.learner.engine.jit_scalar import student_t_normaliser

__all__ = ["GatePool"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


class GatePool:
    """Gates of many experts in stacked arrays, indexed by integer slot.

    Slots are allocated and freed by the owner (:class:`.store.ExpertStore`).  Arrays
    double when full.  :meth:`log_predictive` evaluates ``log t_s(x)`` for many slots with one
    batched product of the cached precisions (cost ~ slots x d^2, §3.4).
    """

    FIELDS = ("count", "kappa", "nu", "mu", "lam", "prec", "logdet", "lognorm", "half_nu_d",
              "inv_nu_c")

    def __init__(self, d: int, mu0: float, kappa0: float, lambda0: float, nu0: float,
                 capacity: int = 16) -> None:
        self.d = d
        self.count = np.zeros(capacity, dtype=np.int64)  # inputs absorbed
        self.kappa = np.zeros(capacity)
        self.nu = np.zeros(capacity)
        self.mu = np.zeros((capacity, d))
        self.lam = np.zeros((capacity, d, d))
        self.prec = np.zeros((capacity, d, d))
        self.logdet = np.zeros(capacity)
        self.lognorm = np.zeros(capacity)
        self.half_nu_d = np.zeros(capacity)
        self.inv_nu_c = np.zeros(capacity)
        self._prior = (float(kappa0), float(nu0), np.full(d, float(mu0)), np.eye(d) * lambda0)
        kappa, nu, mu, lam = self._prior
        # Lambda_0 = lambda0 I: its precision and log-determinant in closed form
        self._prior_prec = np.eye(d) / float(lambda0)
        self._prior_logdet = d * math.log(lambda0)
        self._prior_norm = student_t_normaliser(kappa, nu, self._prior_logdet, d)
        # the empty expert's gate as a one-slot stack, for the kernel (prior_log_predictive)
        self._prior_stack = (np.zeros(1, dtype=np.int64), mu[None].copy(), self._prior_prec[None],
                             *(np.array([v]) for v in self._prior_norm))

    @property
    def capacity(self) -> int:
        """Number of slots allocated."""
        return int(self.kappa.shape[0])

    def grow(self, need: int) -> None:
        """Make room for slot indices ``< need``."""
        cap = self.capacity
        if need <= cap:
            return
        new = max(need, 2 * cap)
        for name in self.FIELDS:
            old = getattr(self, name)
            buf = np.zeros((new, *old.shape[1:]), dtype=old.dtype)
            buf[:cap] = old
            setattr(self, name, buf)

    def copy_slot(self, dst: int, src: int) -> None:
        """Slot ``dst`` becomes a copy of slot ``src``."""
        for name in self.FIELDS:
            arr = getattr(self, name)
            arr[dst] = arr[src]

    def set_prior(self, slot: int) -> None:
        """Slot becomes the prior (no data)."""
        kappa, nu, mu, lam = self._prior
        self.count[slot] = 0
        self.kappa[slot] = kappa
        self.nu[slot] = nu
        self.mu[slot] = mu
        self.lam[slot] = lam
        self.prec[slot] = self._prior_prec
        self.logdet[slot] = self._prior_logdet
        self.lognorm[slot], self.half_nu_d[slot], self.inv_nu_c[slot] = self._prior_norm

    def set_prior_updated(self, slot: int, x: FloatArray) -> None:
        """Slot becomes the prior updated with one input (a new expert's first point)."""
        self.set_prior(slot)
        self.update(slot, x)

    def update(self, slot: int, x: FloatArray) -> None:
        """Absorb one input into the slot's gate (§3.2) and update its cached predictive."""
        self.update_many(np.array([slot], dtype=np.int64), x)

    def update_many(self, slots: IntArray, x: FloatArray) -> None:
        """Absorb the same input into several distinct slots (batched §3.2).

        ``Lambda' = Lambda + w u u^T`` with ``u = x - mu``, ``w = kappa / (kappa + 1)``; the
        precision follows by Sherman-Morrison, ``log|Lambda|`` by the determinant lemma, and
        both are recomputed by Cholesky every 32 updates of a gate.
        """
        # Sherman-Morrison and the determinant lemma: t = w u^T P u,
        # P' = P - w (P u)(P u)^T / (1 + t), log|Lambda'| = log|Lambda| + log(1 + t);
        # every 32nd input of a gate both from Lambda by Cholesky; then the count and the
        # Student-t constants (§3.3): compiled, one pass per slot, no BLAS or LAPACK
        _jit.gate_update(slots, x, self.count, self.kappa, self.nu, self.mu, self.lam,
                         self.prec, self.logdet, self.lognorm, self.half_nu_d, self.inv_nu_c)

    def log_predictive(self, slots: IntArray, x: FloatArray) -> FloatArray:
        """``log t_s(x)`` for every slot in ``slots`` (batched, §3.4)."""
        out: FloatArray = _jit.gate_log_predictive(slots, x, self.mu, self.prec, self.lognorm,
                                                   self.half_nu_d, self.inv_nu_c)
        return out

    def crp_log_terms(self, slots: IntArray, x: FloatArray, npts: IntArray, out: FloatArray
                      ) -> None:
        """``out[s] = log t_s(x) + log n_s`` for every slot ``s`` in ``slots``: the gate and
        CRP prior terms of an expert's putatives (§4), or of its gate probability in a
        prediction (§6), ``npts`` the point counts by slot."""
        _jit.gate_crp_log_terms(slots, x, self.mu, self.prec, self.lognorm, self.half_nu_d,
                                self.inv_nu_c, npts, out)

    def prior_log_predictive(self, x: FloatArray) -> float:
        """``log t_0(x)``, the prior predictive of the empty expert (the slots' kernel)."""
        return float(_jit.gate_log_predictive(self._prior_stack[0], x, *self._prior_stack[1:])[0])

    def predictive(self, slot: int) -> tuple[float, FloatArray, FloatArray]:
        """``(df, loc, shape)`` of slot's Student-t posterior predictive (for scipy)."""
        nu_t = float(self.nu[slot]) - self.d + 1.0
        kappa = float(self.kappa[slot])
        return nu_t, self.mu[slot].copy(), self.lam[slot] * ((kappa + 1.0) / (kappa * nu_t))
