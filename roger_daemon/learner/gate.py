"""The Normal-Inverse-Wishart input gate of one expert (docs/learner-math.md §3).

Each expert's gate is the conjugate NIW posterior over the mean and covariance of the inputs
it generated (paper eq. 1), updated by the rank-1 recursion of §3.2 (:func:`niw_update`, the
textbook form).  The "gate predictive" factor of a putative weight is the posterior
predictive of x, a multivariate Student-t (§3.3)::

    nu_t = nu_n - d + 1,   Sigma_t = Lambda_n (kappa_n + 1) / (kappa_n nu_t)

:class:`NIWGate` is one gate; the model keeps all its experts' gates stacked in one
:class:`~.engine.gates.GatePool` (cached precisions, batched evaluation, §3.4), of which an
:class:`NIWGate` is a one-slot view.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.engine.gates import GatePool

__all__ = ["NIWGate", "niw_update"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


def niw_update(kappa: float, nu: float, mu: FloatArray, lam: FloatArray,
               x: FloatArray) -> tuple[float, float, FloatArray, FloatArray]:
    """One rank-1 NIW posterior update (docs/learner-math.md §3.2; Murphy 2007 eq. 250-254).

    ``kappa' = kappa + 1``, ``nu' = nu + 1``, ``mu' = (kappa mu + x) / (kappa + 1)``,
    ``Lambda' = Lambda + kappa / (kappa + 1) (x - mu)(x - mu)^T``.
    """
    u = x - mu
    lam_new = lam + np.outer(u, u) * (kappa / (kappa + 1.0))
    mu_new = (kappa * mu + x) / (kappa + 1.0)
    return kappa + 1.0, nu + 1.0, mu_new, lam_new


class NIWGate:
    """The NIW posterior of one expert's inputs: a one-slot :class:`GatePool`.

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
        self._pool = GatePool(d, mu0, kappa0, lambda0, nu0, capacity=1)
        self._pool.set_prior(0)
        self._slot = np.zeros(1, dtype=np.int64)

    @property
    def n(self) -> int:
        """Inputs absorbed."""
        return int(self._pool.count[0])

    @property
    def kappa(self) -> float:
        """Posterior ``kappa_n``."""
        return float(self._pool.kappa[0])

    @property
    def nu(self) -> float:
        """Posterior ``nu_n``."""
        return float(self._pool.nu[0])

    @property
    def mu(self) -> FloatArray:
        """Posterior mean ``mu_n``."""
        mu: FloatArray = self._pool.mu[0]
        return mu

    @property
    def lam(self) -> FloatArray:
        """Posterior scale ``Lambda_n``."""
        lam: FloatArray = self._pool.lam[0]
        return lam

    def update(self, x: FloatArray) -> None:
        """Absorb one input (§3.2)."""
        self._pool.update(0, x)

    def predictive(self) -> tuple[float, FloatArray, FloatArray]:
        """``(df, loc, shape)`` of the Student-t posterior predictive (for scipy)."""
        return self._pool.predictive(0)

    def log_predictive(self, x: FloatArray) -> FloatArray:
        """``log t(x)`` for one input (d,) or a batch (m, d)."""
        xs = np.atleast_2d(x)
        return np.array([self._pool.log_predictive(self._slot, xi)[0] for xi in xs])
