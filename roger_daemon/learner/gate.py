"""Normal-Inverse-Wishart input gates (roger-math.md §3): posterior, predictive, batched.

Each expert's gate is the conjugate NIW posterior over the mean and covariance of the inputs
it generated (paper eq. 1).  The "gate predictive" factor of a putative weight is the posterior
predictive of x, a multivariate Student-t (§3.3)::

    nu_t = nu_n - d + 1,   Sigma_t = Lambda_n (kappa_n + 1) / (kappa_n nu_t)

Statistics are kept as (kappa, nu, mu, Lambda) and updated with the rank-1 recursion of §3.2,
never as raw sums of x x^T (pitfall 10).  For evaluation each gate caches ``L^{-1}`` (inverse
Cholesky factor of Lambda) and the log normaliser, so ``log t(x)`` costs one triangular
matrix-vector product; :class:`GatePool` stacks the caches of many gates and evaluates them all
in one batched product (§3.4).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from scipy.special import gammaln

__all__ = ["GatePool", "NIWGate", "niw_update"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


def niw_update(kappa: float, nu: float, mu: FloatArray, lam: FloatArray,
               x: FloatArray) -> tuple[float, float, FloatArray, FloatArray]:
    """One rank-1 NIW posterior update (roger-math.md §3.2; Murphy 2007 eq. 250-254).

    ``kappa' = kappa + 1``, ``nu' = nu + 1``, ``mu' = (kappa mu + x) / (kappa + 1)``,
    ``Lambda' = Lambda + kappa / (kappa + 1) (x - mu)(x - mu)^T``.
    """
    u = x - mu
    lam_new = lam + np.outer(u, u) * (kappa / (kappa + 1.0))
    mu_new = (kappa * mu + x) / (kappa + 1.0)
    return kappa + 1.0, nu + 1.0, mu_new, lam_new


def _predictive_cache(kappa: float, nu: float, lam: FloatArray
                      ) -> tuple[FloatArray, float, float, float]:
    """``(L^{-1}, log normaliser, (nu_t + d)/2, 1/(nu_t c))`` of the Student-t of §3.3."""
    d = lam.shape[0]
    nu_t = nu - d + 1.0
    c = (kappa + 1.0) / (kappa * nu_t)  # Sigma_t = c * Lambda
    chol = np.linalg.cholesky(lam)
    linv = np.linalg.inv(chol)  # lower triangular; numpy's LAPACK (no threaded trsm)
    logdet_sigma = d * math.log(c) + 2.0 * float(np.sum(np.log(np.diagonal(chol))))
    lognorm = (float(gammaln((nu_t + d) / 2.0) - gammaln(nu_t / 2.0))
               - 0.5 * d * math.log(nu_t * math.pi) - 0.5 * logdet_sigma)
    return linv, lognorm, 0.5 * (nu_t + d), 1.0 / (nu_t * c)


class NIWGate:
    """The NIW posterior of one expert's inputs, with a cached predictive.

    Parameters
    ----------
    d : int
        Input dimension.
    mu0, kappa0, lambda0, nu0 : float
        Prior: ``mu0 * 1``, ``kappa0``, ``lambda0 * I`` (an inverse-Wishart *scale*), ``nu0``.

    Examples
    --------
    >>> g = NIWGate(2, 0.0, 0.1, 1.0, 3.0)
    >>> g.update(np.array([1.0, 0.0]))
    >>> g.n, round(g.kappa, 3), g.nu
    (1, 1.1, 4.0)
    """

    def __init__(self, d: int, mu0: float, kappa0: float, lambda0: float, nu0: float) -> None:
        self.d = d
        self.n = 0
        self.kappa = float(kappa0)
        self.nu = float(nu0)
        self.mu = np.full(d, float(mu0))
        self.lam = np.eye(d) * float(lambda0)
        self._refresh()

    def _refresh(self) -> None:
        self.linv, self.lognorm, self.half_nu_d, self.inv_nu_c = _predictive_cache(
            self.kappa, self.nu, self.lam)

    def update(self, x: FloatArray) -> None:
        """Absorb one input (§3.2) and refresh the cached Cholesky factor."""
        self.kappa, self.nu, self.mu, self.lam = niw_update(self.kappa, self.nu, self.mu,
                                                            self.lam, x)
        self.n += 1
        self._refresh()

    def predictive(self) -> tuple[float, FloatArray, FloatArray]:
        """``(df, loc, shape)`` of the Student-t posterior predictive (for scipy)."""
        nu_t = self.nu - self.d + 1.0
        shape = self.lam * ((self.kappa + 1.0) / (self.kappa * nu_t))
        return nu_t, self.mu.copy(), shape

    def log_predictive(self, x: FloatArray) -> FloatArray:
        """``log t(x)`` for one input (d,) or a batch (m, d)."""
        z = (np.atleast_2d(x) - self.mu) @ self.linv.T
        delta = np.einsum("ij,ij->i", z, z)
        out = self.lognorm - self.half_nu_d * np.log1p(delta * self.inv_nu_c)
        return out if np.ndim(x) > 1 else out[:1]


class GatePool:
    """Gates of many experts in stacked arrays, indexed by integer slot.

    Slots are allocated and freed by the owner (the :class:`~.roger.Roger` model).  Arrays
    double when full.  :meth:`log_predictive` evaluates ``log t_s(x)`` for many slots with one
    batched product of the cached inverse Cholesky factors (cost ~ slots x d^2, §3.4).
    """

    def __init__(self, d: int, mu0: float, kappa0: float, lambda0: float, nu0: float,
                 capacity: int = 16) -> None:
        self.d = d
        self.prior = NIWGate(d, mu0, kappa0, lambda0, nu0)
        self.kappa = np.zeros(capacity)
        self.nu = np.zeros(capacity)
        self.mu = np.zeros((capacity, d))
        self.lam = np.zeros((capacity, d, d))
        self.linv = np.zeros((capacity, d, d))
        self.lognorm = np.zeros(capacity)
        self.half_nu_d = np.zeros(capacity)
        self.inv_nu_c = np.zeros(capacity)

    _FIELDS = ("kappa", "nu", "mu", "lam", "linv", "lognorm", "half_nu_d", "inv_nu_c")

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
        for name in self._FIELDS:
            old = getattr(self, name)
            buf = np.zeros((new, *old.shape[1:]))
            buf[:cap] = old
            setattr(self, name, buf)

    def copy_slot(self, dst: int, src: int) -> None:
        """Slot ``dst`` becomes a copy of slot ``src``."""
        for name in self._FIELDS:
            arr = getattr(self, name)
            arr[dst] = arr[src]

    def set_prior_updated(self, slot: int, x: FloatArray) -> None:
        """Slot becomes the prior updated with one input (a new expert's first point)."""
        p = self.prior
        self._store(slot, *niw_update(p.kappa, p.nu, p.mu, p.lam, x))

    def update(self, slot: int, x: FloatArray) -> None:
        """Absorb one input into slot's gate (§3.2)."""
        self._store(slot, *niw_update(float(self.kappa[slot]), float(self.nu[slot]),
                                      self.mu[slot], self.lam[slot], x))

    def _store(self, slot: int, kappa: float, nu: float, mu: FloatArray,
               lam: FloatArray) -> None:
        self.kappa[slot] = kappa
        self.nu[slot] = nu
        self.mu[slot] = mu
        self.lam[slot] = lam
        (self.linv[slot], self.lognorm[slot], self.half_nu_d[slot],
         self.inv_nu_c[slot]) = _predictive_cache(kappa, nu, lam)

    def log_predictive(self, slots: IntArray, x: FloatArray) -> FloatArray:
        """``log t_s(x)`` for every slot in ``slots`` (batched, §3.4)."""
        diff = x - self.mu[slots]
        z = np.matmul(self.linv[slots], diff[:, :, None])[:, :, 0]
        delta = np.einsum("ij,ij->i", z, z)
        return self.lognorm[slots] - self.half_nu_d[slots] * np.log1p(delta * self.inv_nu_c[slots])

    def prior_log_predictive(self, x: FloatArray) -> float:
        """``log t_0(x)``, the prior predictive of the empty expert."""
        return float(self.prior.log_predictive(x)[0])
