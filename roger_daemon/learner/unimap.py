"""The unimap baseline: one sparse online GP on all data (the paper's "DPA").

Same API as :class:`~.roger.Roger`: ``n_experts`` is 1 once anything has been learned,
``assignments()`` is all zeros, the multimap has one branch with gate probability 1.  On a
multimap (one input, several outputs) it predicts near the average of the branches, which is
what ROGER is meant to avoid.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.kernel import RBFKernel
from roger_daemon.learner.model_args import Seed, resolve_model_args, spawn_generators
from roger_daemon.learner.params import RogerParams
from roger_daemon.learner.prediction import ExpertPrediction, MultimapTable, Prediction
from roger_daemon.learner.roger_terms import new_expert
from roger_daemon.learner.scaling import AffineScaling, as_vector
from roger_daemon.learner.sogp import SparseOnlineGP
from roger_daemon.learner.state import (
    generator_from_state,
    model_meta,
    pack_experts,
    unpack_experts,
    unpack_meta,
)

__all__ = ["UnimapGP"]

IntArray = npt.NDArray[np.int64]


class UnimapGP:
    """One multi-output sparse online GP with ROGER's kernel, noise, capacity and scaling.

    Parameters
    ----------
    d_x, d_y : int
        Input and output dimensions.
    params : RogerParams, optional
        Only ``theta_w``, ``theta_n``, ``beta``, the kernel/likelihood options, the novelty
        threshold, the scalings, ``input_weights`` and ``gp_prior_mean`` are used.
    seed : int, numpy Generator or None
        Accepted for API symmetry; the baseline is deterministic and draws nothing.

    Examples
    --------
    >>> base = UnimapGP(d_x=1, d_y=1)
    >>> for i in range(40):
    ...     base.learn_one([0.5], [(-1.0) ** i])  # two branches: +1 and -1
    >>> abs(float(base.predict_one([0.5]).mean[0])) < 0.1  # the average
    True
    """

    kind = "unimap"

    def __init__(self, d_x: int, d_y: int, params: RogerParams | None = None,
                 seed: Seed = None) -> None:
        self.d_x, self.d_y, self.params = resolve_model_args(d_x, d_y, params)
        self._learn_rng, self._predict_rng = spawn_generators(seed)
        p = self.params
        self._scaling = AffineScaling(p, self.d_x, self.d_y)
        self.kernel = RBFKernel(p.theta_w, self._scaling.d_model, p.kernel_dim_scaling)
        self._gp = self._new_gp()

    def _new_gp(self) -> SparseOnlineGP:
        return new_expert(self.params, self._scaling.d_model, self.d_y, self.kernel)

    @property
    def n_learned(self) -> int:
        """Points learned so far."""
        return self._gp.n_points

    @property
    def n_experts(self) -> int:
        """1 once anything has been learned, else 0."""
        return 1 if self._gp.n_points else 0

    def learn_one(self, x: npt.ArrayLike, y: npt.ArrayLike) -> None:
        """Learn one pair; ``ValueError`` (model unchanged) on bad shape or non-finite values."""
        xs = self._scaling.x_in(as_vector("x", x, self.d_x))
        ys = self._scaling.y_in(as_vector("y", y, self.d_y))
        self._gp.update(xs, ys)

    def predict_one(self, x: npt.ArrayLike, *, rng: np.random.Generator | None = None
                    ) -> Prediction:
        """Predictive mean and variance of the single GP (the prior before any learning)."""
        xs = self._scaling.x_in(as_vector("x", x, self.d_x))
        mean, var = self._gp.predict(xs)
        return Prediction(mean=self._scaling.mean_out(mean), var=self._scaling.var_out(var),
                          expert_id=0 if self._gp.n_points else -1, gate_prob=1.0)

    def predict_multimap(self, x: npt.ArrayLike) -> list[ExpertPrediction]:
        """A one-branch multimap (empty before any learning)."""
        if not self._gp.n_points:
            as_vector("x", x, self.d_x)
            return []
        pred = self.predict_one(x)
        return [ExpertPrediction(expert_id=0, gate_prob=1.0, mean=pred.mean, var=pred.var,
                                 n_points=self._gp.n_points)]

    def predict_with_multimap(self, x: npt.ArrayLike, *, rng: np.random.Generator | None = None
                              ) -> tuple[Prediction, list[ExpertPrediction]]:
        """``(predict_one(x), predict_multimap(x))`` from one GP evaluation (the rows of
        :meth:`predict_table`)."""
        pred, table = self.predict_table(x, rng=rng)
        return pred, table.experts()

    def predict_table(self, x: npt.ArrayLike, *, rng: np.random.Generator | None = None
                      ) -> tuple[Prediction, MultimapTable]:
        """``predict_with_multimap(x)`` with the multimap as a table (one row, or none)."""
        pred = self.predict_one(x, rng=rng)
        if not self._gp.n_points:
            return pred, MultimapTable.empty(self.d_y)
        return pred, MultimapTable([0], [1.0], pred.mean[None, :], pred.var[None, :],
                                   [self._gp.n_points])

    def assignments(self) -> IntArray:
        """All zeros: every point belongs to the one expert."""
        return np.zeros(self._gp.n_points, dtype=np.int64)

    def unsettled_points(self) -> IntArray:
        """None: a point's (only) expert never changes."""
        return np.zeros(0, dtype=np.int64)

    def assignments_at(self, points: npt.ArrayLike) -> IntArray:
        """``assignments()[points]``: zeros."""
        return self.assignments()[np.asarray(points, dtype=np.int64)]

    def expert_sizes(self) -> dict[int, int]:
        """``{0: points learned}`` (empty before any learning)."""
        return {0: self._gp.n_points} if self._gp.n_points else {}

    def basis_sizes(self) -> dict[int, int]:
        """``{0: basis vectors}`` (empty before any learning)."""
        return {0: self._gp.n} if self._gp.n_points else {}

    @property
    def gp(self) -> SparseOnlineGP:
        """The underlying sparse online GP."""
        return self._gp

    def state_dict(self) -> dict[str, np.ndarray]:
        """Flat named arrays plus JSON metadata (no pickle)."""
        out = pack_experts([self._gp], self._scaling.d_model, self.d_y)
        out["meta"] = model_meta(self.kind, self.d_x, self.d_y, self.params.to_mapping(),
                                 (self._learn_rng, self._predict_rng))
        return out

    @classmethod
    def from_state_dict(cls, state: Mapping[str, np.ndarray]) -> UnimapGP:
        """Rebuild the model from :meth:`state_dict` output (or ``np.load`` of it)."""
        state = {k: np.asarray(state[k]) for k in state}
        meta = unpack_meta(state, cls.kind)
        model = cls(int(meta["d_x"]), int(meta["d_y"]), RogerParams.from_mapping(meta["params"]))
        model._learn_rng = generator_from_state(meta["rng_learn"])
        model._predict_rng = generator_from_state(meta["rng_predict"])
        (model._gp,) = unpack_experts(state, model._new_gp)
        return model
