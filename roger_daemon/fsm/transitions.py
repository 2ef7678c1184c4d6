"""Which expert follows which, and when: the learned transition model (docs/autonomy.md).

For every ordered pair of states ``(s, j)`` seen in a state sequence (``s = -1``: an episode's
start), the model counts how often ``j`` followed ``s`` and keeps a Normal-Inverse-Wishart
posterior over the feature vectors at which it did (the same conjugate statistics as ROGER's
gates, docs/learner-math.md §3, here over :meth:`~roger_daemon.fsm.memory.Memory.features`).
The next state's score given the current one is a generative classifier::

    log P(j | s, phi) = log N_sj + log t_sj(phi) + const,

``t_sj`` the Student-t posterior predictive of the pair's NIW (§3.3). A self pair ``(s, s)``
learns where a state persists, a switch pair where it ends; durations enter through the
"time in state" feature. Learning is one rank-1 update of one pair per observed tick
(:meth:`TransitionModel.learn_one`, O(D^2)); scoring evaluates the pairs leaving ``s``, one
batched quadratic form (:meth:`TransitionModel.log_scores`).
"""

from __future__ import annotations

import math
from typing import Any, cast

import numpy as np
import numpy.typing as npt
from scipy.special import gammaln

__all__ = ["TransitionModel"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

_NO_ROWS = np.zeros(0, dtype=np.int64)


class TransitionModel:
    """Counts and NIW feature statistics of every observed state pair (module docstring).

    Parameters
    ----------
    dim : int
        Feature dimension D.
    kappa0, lambda0 : float
        NIW prior: mean 0 with strength ``kappa0``, scale matrix ``lambda0 * I``.
    nu0 : float, optional
        Prior degrees of freedom, ``> D - 1``; default ``D + 1``.
    """

    def __init__(self, dim: int, kappa0: float = 0.1, lambda0: float = 0.1,
                 nu0: float | None = None) -> None:
        if isinstance(dim, bool) or not isinstance(dim, int) or dim < 1:
            raise ValueError(f"TransitionModel: dim must be an integer >= 1, got {dim!r}")
        nu = float(dim + 1) if nu0 is None else float(nu0)
        if not (kappa0 > 0 and lambda0 > 0 and nu > dim - 1):
            raise ValueError(f"TransitionModel: kappa0 and lambda0 must be > 0 and nu0 > dim - 1, "
                             f"got {kappa0}, {lambda0}, {nu}")
        self.dim = dim
        self.kappa0, self.lambda0, self.nu0 = float(kappa0), float(lambda0), nu
        self._index: dict[tuple[int, int], int] = {}  # (s, j) -> row of the arrays below
        self.n_pairs = 0
        self._grow(0)
        self._by_source: dict[int, list[int]] = {}
        self._rows: dict[int, IntArray] = {}  # the rows of _by_source, as arrays (.jit_fsm)
        self._cache: dict[int, tuple[IntArray, FloatArray, FloatArray, FloatArray,
                                     FloatArray]] = {}

    # -- storage: rows of arrays with room to grow (no copy per new pair) ----------------------

    def _grow(self, need: int) -> None:
        """Room for ``need`` pairs: the buffers, their first :attr:`n_pairs` rows kept. Besides
        the statistics, per pair its compiled Student-t terms (:mod:`.jit_fsm`: ``linv``,
        ``lnorm``, ``valid``; derived from the statistics, never saved)."""
        cap = max(8, 2 * need) if need else 8
        d, n = self.dim, self.n_pairs
        old = getattr(self, "_buf", None)
        buf: dict[str, Any] = {
            "pairs": np.zeros((cap, 2), dtype=np.int64), "count": np.zeros(cap, np.int64),
            "mu": np.zeros((cap, d)), "lam": np.zeros((cap, d, d)),
            "linv": np.zeros((cap, d, d)), "lnorm": np.zeros((cap, 4)),
            "valid": np.zeros(cap, dtype=np.bool_)}
        if old is not None:
            for k, v in buf.items():
                v[:n] = old[k][:n]
        self._buf = buf

    @property
    def pairs(self) -> IntArray:
        """``(s, j)`` of every pair, one row each (a view)."""
        return cast(IntArray, self._buf["pairs"][:self.n_pairs])

    @property
    def count(self) -> IntArray:
        """How often each pair was observed (a view)."""
        return cast(IntArray, self._buf["count"][:self.n_pairs])

    @property
    def mu(self) -> FloatArray:
        """The NIW posterior means (a view)."""
        return cast(FloatArray, self._buf["mu"][:self.n_pairs])

    @property
    def lam(self) -> FloatArray:
        """The NIW posterior scale matrices ``Lambda_n`` (a view)."""
        return cast(FloatArray, self._buf["lam"][:self.n_pairs])

    # -- learning ----------------------------------------------------------------------------

    def learn_one(self, prev: int, state: int, phi: npt.ArrayLike) -> None:
        """One observed transition ``prev -> state`` at features ``phi`` (a self pair when the
        state did not change). Rank-1 NIW update (docs/learner-math.md §3.2)."""
        x = np.asarray(phi, dtype=np.float64)
        if x.shape != (self.dim,) or not np.isfinite(x).all():
            raise ValueError(f"TransitionModel: phi must be {self.dim} finite floats, got "
                             f"shape {x.shape}")
        r = self.row(prev, state)
        n = int(self.count[r])
        kappa = self.kappa0 + n
        u = x - self.mu[r]
        self.lam[r] += np.outer(u, u) * (kappa / (kappa + 1.0))
        self.mu[r] += u / (kappa + 1.0)
        self.count[r] = n + 1
        self.learned(r)

    def row(self, prev: int, state: int) -> int:
        """The row of pair ``(prev, state)``, added (count 0, the prior) if it is new."""
        key = (int(prev), int(state))
        r = self._index.get(key)
        return self._add_pair(key) if r is None else r

    def learned(self, r: int) -> None:
        """Row ``r``'s statistics changed: its cached Student-t terms are stale."""
        self._cache.pop(int(self.pairs[r, 0]), None)
        self._buf["valid"][r] = False

    def _add_pair(self, key: tuple[int, int]) -> int:
        r = self.n_pairs
        if r == len(self._buf["count"]):
            self._grow(r + 1)
        self._index[key] = r
        self._buf["pairs"][r] = key
        self._buf["count"][r] = 0
        self._buf["mu"][r] = 0.0
        self._buf["lam"][r] = np.eye(self.dim) * self.lambda0
        self._buf["valid"][r] = False
        self.n_pairs = r + 1
        self._by_source.setdefault(key[0], []).append(r)
        self._rows[key[0]] = np.array(self._by_source[key[0]], dtype=np.int64)
        return r

    def source_rows(self, prev: int) -> IntArray:
        """The rows of the pairs leaving ``prev``, in order of first observation."""
        rows = self._rows.get(prev)
        return _NO_ROWS if rows is None else rows

    # -- scoring -----------------------------------------------------------------------------

    def sources(self) -> list[int]:
        """States with at least one observed successor (``-1`` = an episode's start)."""
        return sorted(self._by_source)

    def successors(self, prev: int) -> IntArray:
        """The states seen to follow ``prev`` (itself included if it persisted)."""
        rows = self._by_source.get(int(prev), [])
        return self.pairs[rows, 1].copy() if rows else np.zeros(0, dtype=np.int64)

    def log_scores(self, prev: int, phi: npt.ArrayLike) -> tuple[IntArray, FloatArray]:
        """``(states, log N_sj + log t_sj(phi))`` for every state seen to follow ``prev``."""
        states, lcount, mu, prec, lognorm, half = self._stack(int(prev))
        if states.size == 0:
            return states, np.zeros(0)
        u = np.asarray(phi, dtype=np.float64)[None, :] - mu
        delta = np.einsum("kd,kde,ke->k", u, prec, u)
        return states, lcount + lognorm - half[:, 0] * np.log1p(delta / half[:, 1])

    def _stack(self, prev: int) -> tuple[IntArray, FloatArray, FloatArray, FloatArray,
                                         FloatArray, FloatArray]:
        """Per successor of ``prev``: the Student-t's location, precision, log normaliser and
        ``((nu_t + D) / 2, nu_t)``, cached until a pair of ``prev`` learns (§3.3)."""
        rows = self._by_source.get(prev, [])
        if not rows:
            z = np.zeros(0)
            return np.zeros(0, dtype=np.int64), z, z, z, z, z
        cached = self._cache.get(prev)
        if cached is None:
            cached = self._predictives(rows)
            self._cache[prev] = cached
        states, mu, prec, lognorm, half = cached
        return states, np.log(self.count[rows].astype(np.float64)), mu, prec, lognorm, half

    def _predictives(self, rows: list[int]) -> tuple[IntArray, FloatArray, FloatArray,
                                                     FloatArray, FloatArray]:
        d = self.dim
        n = self.count[rows].astype(np.float64)
        kappa = self.kappa0 + n
        nu_t = self.nu0 + n - d + 1.0
        c = (kappa + 1.0) / (kappa * nu_t)  # Sigma_t = c Lambda_n
        prec = np.empty((len(rows), d, d))
        lognorm = np.empty(len(rows))
        for k, r in enumerate(rows):
            chol = np.linalg.cholesky(self.lam[r])
            inv = np.linalg.inv(chol)
            prec[k] = (inv.T @ inv) / c[k]
            logdet = d * math.log(c[k]) + 2.0 * float(np.sum(np.log(np.diag(chol))))
            lognorm[k] = (gammaln((nu_t[k] + d) / 2.0) - gammaln(nu_t[k] / 2.0)
                          - 0.5 * d * math.log(nu_t[k] * math.pi) - 0.5 * logdet)
        half = np.stack([(nu_t + d) / 2.0, nu_t], axis=1)
        return self.pairs[rows, 1].copy(), self.mu[rows].copy(), prec, lognorm, half

    # -- introspection and state ---------------------------------------------------------------

    def table(self) -> list[dict[str, Any]]:
        """Every pair: ``{"from", "to", "count", "mean"}`` (the mean feature vector)."""
        return [{"from": int(s), "to": int(j), "count": int(self.count[r]),
                 "mean": [float(v) for v in self.mu[r]]}
                for r, (s, j) in enumerate(self.pairs.tolist())]

    def state_arrays(self) -> dict[str, np.ndarray]:
        """Named arrays (no objects): the pairs, counts, means and scale matrices."""
        return {"pairs": self.pairs.copy(), "count": self.count.copy(), "mu": self.mu.copy(),
                "lam": self.lam.copy(),
                "prior": np.array([self.dim, self.kappa0, self.lambda0, self.nu0])}

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> TransitionModel:
        """Rebuild from :meth:`state_arrays` (continues exactly as the saved model)."""
        prior = np.asarray(arrays["prior"], dtype=np.float64)
        model = cls(int(prior[0]), float(prior[1]), float(prior[2]), float(prior[3]))
        pairs = np.asarray(arrays["pairs"], dtype=np.int64).reshape(-1, 2)
        count = np.asarray(arrays["count"], dtype=np.int64).reshape(-1)
        mu = np.asarray(arrays["mu"], dtype=np.float64).reshape(-1, model.dim)
        lam = np.asarray(arrays["lam"], dtype=np.float64).reshape(-1, model.dim, model.dim)
        if not len(pairs) == len(count) == len(mu) == len(lam):
            raise ValueError("TransitionModel: saved arrays disagree in length")
        for r, (s, j) in enumerate(pairs.tolist()):
            if (s, j) in model._index:
                raise ValueError(f"TransitionModel: pair {(s, j)} saved twice")
            model.row(s, j)
            model.count[r], model.mu[r], model.lam[r] = count[r], mu[r], lam[r]
        return model
