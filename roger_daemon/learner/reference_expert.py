"""One ROGER expert in plain numpy, for :mod:`.reference`: an NIW input gate and a sparse
online GP (Grollman & Jenkins 2010, eq. 1; docs/learner-math.md §2 and §3).

Dense matrices and one numpy call per equation: the page to read beside Csató's thesis.  The
fast learner's experts (:mod:`.sogp`, :mod:`.gate`) compute the same quantities packed and
compiled; tests/learner/test_reference.py checks that the two agree.  The constants below are
the fast learner's (checked by the same tests).
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import numpy.typing as npt
from scipy.linalg import cho_solve

from roger_daemon.learner.params import RogerParams

__all__ = ["GAMMA_FLOOR", "K_STAR", "LATENT_FLOOR", "NEAR_DEPENDENT", "Q_DRIFT_TOL",
           "ReferenceExpert", "ReferenceGP", "ReferenceGate", "gaussian_log_density",
           "kernel_gamma"]

FloatArray = npt.NDArray[np.float64]

K_STAR = 1.0  # k(x, x) of the unit-amplitude RBF (§2.3)
LATENT_FLOOR = 1e-12  # k* + k^T C k is clamped here (§2.4)
GAMMA_FLOOR = 1e-12  # a projection residual below this is 0 (§2.5 step 3)
NEAR_DEPENDENT = 1e-3  # a step with 0 < gamma < this x k* re-inverts Q (§7 pitfall 6)
Q_DRIFT_TOL = 1e-6  # gamma < -tol k* or min Q_ii < (1 - tol) / k*: Q has drifted (pitfall 6)
Q_JITTER = 1e-10  # x k*: the first jitter when K_B's Cholesky factorisation fails


def kernel_gamma(params: RogerParams, d_m: int) -> float:
    """``g`` of ``k(a, b) = exp(-g |a - b|^2)``: ``1 / (2 theta_w^2 s)``, ``s = 1`` or ``d_m``
    (``kernel_dim_scaling="grollman"``, fidelity switch 1; §2.3)."""
    s = float(d_m) if params.kernel_dim_scaling == "grollman" else 1.0
    return 1.0 / (2.0 * params.theta_w**2 * s)


def _kernel(basis: FloatArray, x: FloatArray, g: float) -> FloatArray:
    diff = basis - x
    out: FloatArray = np.exp(-g * np.einsum("ij,ij->i", diff, diff))
    return out


def gaussian_log_density(sq_err: float, var: float, dims: int) -> float:
    """``log N(y; mu, var I)`` from ``|y - mu|^2`` (§2.4); ``dims = d_y``, or 1 with
    ``likelihood_normaliser="grollman"`` (fidelity switch 2)."""
    return -0.5 * dims * (math.log(2.0 * math.pi) + math.log(var)) - 0.5 * sq_err / var


class ReferenceGP:
    """Csató & Opper's sparse online GP with ``d_y`` outputs sharing ``C`` and ``Q`` (§2.2).

    ``B`` (n, d) basis, ``A`` (n, d_y) mean coefficients (one more column ``a1`` with
    ``gp_prior_mean="expert"``, §8), ``C`` and ``Q = K_B^-1`` (n, n), ``m`` the prior mean.
    ``stats`` counts the discrete events (tests check that a lever's stream exercises it).
    """

    def __init__(self, params: RogerParams, d_m: int, d_y: int, stats: Counter[str]) -> None:
        self.p, self.d_y, self.stats = params, d_y, stats
        self.g = kernel_gamma(params, d_m)
        self.prior_mean = params.gp_prior_mean == "expert"
        cols = d_y + 1 if self.prior_mean else d_y
        self.B, self.A = np.zeros((0, d_m)), np.zeros((0, cols))
        self.C, self.Q = np.zeros((0, 0)), np.zeros((0, 0))
        self.m = np.zeros(d_y)
        self.n_points = 0

    @property
    def n(self) -> int:
        """Basis vectors."""
        return int(self.B.shape[0])

    def copy(self) -> ReferenceGP:
        """An independent copy (copy-on-write of a particle's chosen expert)."""
        out = ReferenceGP.__new__(ReferenceGP)
        out.__dict__.update(self.__dict__)
        out.B, out.A, out.m = self.B.copy(), self.A.copy(), self.m.copy()
        out.C, out.Q = self.C.copy(), self.Q.copy()
        return out

    def predict(self, x: FloatArray) -> tuple[FloatArray, float]:
        """Mean ``m + A^T k_x`` (d_y) and latent variance ``max(k* + k^T C k, 1e-12)`` (§2.4)."""
        if self.n == 0:
            return self.m.copy(), K_STAR
        k = _kernel(self.B, x, self.g)
        return (self.m + self.A[:, : self.d_y].T @ k,
                max(K_STAR + float(k @ self.C @ k), LATENT_FLOOR))

    def _targets(self, y: FloatArray) -> FloatArray:
        """What the columns of ``A`` fit: ``y - m`` (and 1 for ``a1``, §8)."""
        return np.append(y - self.m, 1.0) if self.prior_mean else y - self.m

    def learn(self, x: FloatArray, y: FloatArray) -> None:
        """Learn one pair: Csató's thesis eq. 2.46 with the KL projection (§2.5 steps 1-6)."""
        s0, t = self.p.theta_n, self._targets(y)
        self.n_points += 1
        if self.n == 0:  # the first point (§2.5)
            self.B, self.A = x[None].copy(), t[None] / (K_STAR + s0)
            self.C, self.Q = np.array([[-1.0 / (K_STAR + s0)]]), np.array([[1.0 / K_STAR]])
            self._shift_mean(y)
            return
        was_full = self.n == self.p.beta
        k = _kernel(self.B, x, self.g)  # step 1
        ck = self.C @ k
        latent = max(K_STAR + float(k @ ck), LATENT_FLOOR)
        r = -1.0 / (s0 + latent)  # step 2: Csató's K2 and K1
        q = (t - self.A.T @ k) / (s0 + latent)
        e, gamma = self._projection(k)  # step 3
        novel = gamma >= self.p.novelty_threshold * K_STAR and gamma > 0.0
        if novel:
            self._add(x, ck, e, gamma, r, q)  # step 4b
        else:
            self._project(ck, e, gamma, r, q)  # step 4a
        while self.n > self.p.beta:  # step 5: capacity, KL-optimal deletion (§2.7)
            self._delete(self._deletion_choice())
            self.stats["capacity deletions"] += 1
        self._clean_up()  # step 6
        # pitfall 6: a 1/gamma-sized term just entered Q (or, in an expert with room, a
        # projection came close to the basis): re-invert; the fast learner's hot path for a
        # full expert skips this after a projection, which leaves Q unchanged in exact math
        if 0.0 < gamma < NEAR_DEPENDENT * K_STAR and self.n > 1 and (novel or not was_full):
            self.refresh_q()
        self._shift_mean(y)

    def _projection(self, k: FloatArray) -> tuple[FloatArray, float]:
        """Step 3: ``e = Q k`` and the residual ``gamma = k* - k^T e``, after re-inverting
        ``Q`` if it has drifted (``gamma < 0`` or ``Q_ii < 1/k*``: impossible in exact
        arithmetic, pitfall 6); ``gamma`` below 1e-12 is 0."""
        e = self.Q @ k
        gamma = K_STAR - k @ e
        if (gamma < -Q_DRIFT_TOL * K_STAR
                or np.min(np.diag(self.Q)) * K_STAR < 1.0 - Q_DRIFT_TOL):
            self.stats["drift re-inversions"] += 1
            self.refresh_q()
            e = self.Q @ k
            gamma = K_STAR - k @ e
        return e, (0.0 if gamma < GAMMA_FLOOR else float(gamma))

    def _project(self, ck: FloatArray, e: FloatArray, gamma: float, r: float,
                 q: FloatArray) -> None:
        """Step 4a: the basis unchanged; ``eta = 1/(1 + gamma r)``, ``s = C k + e``."""
        self.stats["projections"] += 1
        eta = 1.0 / (1.0 + gamma * r)
        s = ck + e
        self.A = self.A + eta * np.outer(s, q)
        self.C = self.C + r * eta * np.outer(s, s)

    def _add(self, x: FloatArray, ck: FloatArray, e: FloatArray, gamma: float, r: float,
             q: FloatArray) -> None:
        """Step 4b: ``x`` becomes basis vector ``n`` (eq. 2.46; ``Q`` by thesis eq. 3.5)."""
        self.stats["additions"] += 1
        s, e1 = np.append(ck, 1.0), np.append(e, -1.0)
        self.A = np.vstack([self.A, np.zeros(self.A.shape[1])]) + np.outer(s, q)
        self.C = np.pad(self.C, (0, 1)) + r * np.outer(s, s)
        self.Q = np.pad(self.Q, (0, 1)) + np.outer(e1, e1) / gamma
        self.B = np.vstack([self.B, x])

    def _deletion_choice(self) -> int:
        """``argmin_i |A_i|^2 / (Q_ii + C_ii)``, the outputs' columns only (§2.7)."""
        a = self.A[:, : self.d_y]
        den = np.maximum(np.diag(self.Q) + np.diag(self.C), 1e-300)
        return int(np.argmin(np.einsum("ij,ij->i", a, a) / den))

    def _delete(self, i: int) -> None:
        """Remove basis vector ``i`` (thesis App. G(g), §2.7); the last one takes its place."""
        keep = list(range(self.n - 1))
        if i != self.n - 1:
            keep[i] = self.n - 1
        a_s, c_s, q_s = self.A[i].copy(), self.C[i, i], self.Q[i, i]
        qv, cv = self.Q[keep, i], self.C[keep, i]
        w = qv + cv
        inv = 1.0 / (q_s + c_s) if q_s + c_s > 0.0 else 0.0  # a broken q* + c*: Q-only removal
        sub = np.ix_(keep, keep)
        self.A = self.A[keep] - np.outer(w, a_s) * inv
        self.C = self.C[sub] + np.outer(qv, qv) / q_s - np.outer(w, w) * inv
        self.Q = self.Q[sub] - np.outer(qv, qv) / q_s
        self.B = self.B[keep]

    def _clean_up(self) -> None:
        """Step 6: while ``1/Q_ii`` (the squared distance of ``b_i`` from the others' span) is
        below ``threshold / 1000`` for the largest ``Q_ii``, delete that basis vector."""
        floor = self.p.novelty_threshold * 1e-3
        while self.n > 1 and floor > 0.0:
            i = int(np.argmax(np.diag(self.Q)))
            with np.errstate(divide="ignore"):
                if 1.0 / np.float64(self.Q[i, i]) >= floor:
                    return
            self._delete(i)
            self.stats["clean-up deletions"] += 1

    def refresh_q(self) -> None:
        """``Q = K_B^-1`` by Cholesky, ``K_B`` recomputed from the basis (pitfall 6)."""
        self.stats["re-inversions"] += 1
        gram = np.array([_kernel(self.B, b, self.g) for b in self.B])
        jitter = 0.0
        while True:  # K_B is SPD in exact arithmetic; jitter only if round-off says no
            try:
                low = np.linalg.cholesky(gram + jitter * np.eye(self.n))
                break
            except np.linalg.LinAlgError:
                jitter = max(10.0 * jitter, Q_JITTER * K_STAR)
        self.Q = cho_solve((low, True), np.eye(self.n))

    def _shift_mean(self, y: FloatArray) -> None:
        """§8: ``m`` moves to the running mean; ``A <- A - a1 dm^T`` refits ``y_i - m``."""
        if self.prior_mean:
            dm = (y - self.m) / self.n_points
            self.m = self.m + dm
            self.A[:, : self.d_y] -= np.outer(self.A[:, self.d_y], dm)


@dataclass(frozen=True)
class ReferenceGate:
    """The NIW posterior over an expert's inputs (§3): ``kappa, nu, mu, Lambda``."""

    kappa: float
    nu: float
    mu: FloatArray
    lam: FloatArray

    @classmethod
    def prior(cls, params: RogerParams, d: int) -> ReferenceGate:
        """``mu0 1``, ``kappa0``, ``Lambda0 = lambda0 I`` (a scale matrix), ``nu0`` (§3;
        resolved for the data's dimension by the model's constructor)."""
        assert params.nu0 is not None, "params not resolved for the data (RogerParams.for_dims)"
        return cls(params.kappa0, params.nu0, np.full(d, params.mu0), params.lambda0 * np.eye(d))

    def updated(self, x: FloatArray) -> ReferenceGate:
        """§3.2: ``kappa + 1``, ``nu + 1``, ``(kappa mu + x)/(kappa + 1)``,
        ``Lambda + kappa/(kappa + 1) (x - mu)(x - mu)^T`` (never raw sums, pitfall 10)."""
        u = x - self.mu
        return ReferenceGate(self.kappa + 1.0, self.nu + 1.0,
                             (self.kappa * self.mu + x) / (self.kappa + 1.0),
                             self.lam + (self.kappa / (self.kappa + 1.0)) * np.outer(u, u))

    def log_predictive(self, x: FloatArray) -> float:
        """§3.3: the Student-t with ``nu_t = nu - d + 1`` and scale
        ``Sigma_t = c Lambda``, ``c = (kappa + 1) / (kappa nu_t)``."""
        d = self.mu.size
        nu_t = self.nu - d + 1.0
        c = (self.kappa + 1.0) / (self.kappa * nu_t)
        prec, logdet_lam = self._factor
        u = x - self.mu
        delta = (u @ prec @ u) / c  # (x - mu)^T Sigma_t^-1 (x - mu)
        log_norm = (math.lgamma((nu_t + d) / 2.0) - math.lgamma(nu_t / 2.0)
                    - 0.5 * d * math.log(nu_t * math.pi) - 0.5 * (d * math.log(c) + logdet_lam))
        return log_norm - 0.5 * (nu_t + d) * math.log1p(delta / nu_t)

    @cached_property
    def _factor(self) -> tuple[FloatArray, float]:
        """``Lambda^-1`` and ``log|Lambda|`` by Cholesky (§3.4: cached per gate)."""
        low = np.linalg.cholesky(self.lam)
        prec = cho_solve((low, True), np.eye(self.mu.size))
        return prec, 2.0 * float(np.sum(np.log(np.diag(low))))


@dataclass(frozen=True)
class ReferenceExpert:
    """One expert of a particle (paper eq. 1): its id, point count ``n_k``, gate and GP.
    Never changed once built: learning makes a new one (particles share experts)."""

    id: int
    count: int
    gate: ReferenceGate
    gp: ReferenceGP

    def with_point(self, x: FloatArray, y: FloatArray) -> ReferenceExpert:
        """This expert after learning ``(x, y)`` (Algorithm 1, last line)."""
        gp = self.gp.copy()
        gp.learn(x, y)
        return ReferenceExpert(self.id, self.count + 1, self.gate.updated(x), gp)
