"""The fixed terms of one ROGER model, from its parameters and dimensions: what its learning
step (:mod:`.roger_step`) and its predictions (:mod:`.roger_predict`) read besides its experts
(docs/learner-math.md §4 and §6).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from roger_daemon.learner.engine.gates import GatePool
from roger_daemon.learner.engine.store import ExpertStore
from roger_daemon.learner.kernel import RBFKernel
from roger_daemon.learner.params import RogerParams
from roger_daemon.learner.scaling import AffineScaling
from roger_daemon.learner.sogp import LATENT_FLOOR, SparseOnlineGP, likelihood_dims

__all__ = ["Experts", "ModelTerms", "new_expert"]

#: a ROGER model's experts: sparse online GPs in slots (:class:`.engine.store.ExpertStore`)
Experts = ExpertStore[SparseOnlineGP]


def new_expert(params: RogerParams, d_model: int, d_y: int, kernel: RBFKernel) -> SparseOnlineGP:
    """An empty expert GP with ``params``' noise, capacity, novelty rule, normaliser and prior
    mean, on ``d_model`` inputs (after the scaling's input weights) and ``d_y`` outputs."""
    return SparseOnlineGP(d_model, d_y, kernel, params.theta_n, params.beta,
                          params.novelty_threshold, params.likelihood_normaliser,
                          prior_mean=params.gp_prior_mean == "expert")


@dataclass(frozen=True)
class ModelTerms:
    """One model's parameters, scaling and kernel, and the constants of its putatives.

    ``log_alpha``: the CRP weight of a new expert (§4); ``empty_var``: the empty expert's
    predictive variance, ``y ~ N(0, (k* + s0^2) I)``; ``ll_dims``: the dimensions in the
    Gaussian's normalising constant (:func:`.sogp.likelihood_dims`); ``gp_bound``: an upper
    bound of any expert's ``log N(y; mu, s^2 I)``, since ``s^2 >= s0^2`` (+ the latent floor),
    for the opt-in pruning (``prune_log_margin``).
    """

    params: RogerParams
    d_x: int
    d_y: int
    scaling: AffineScaling
    kernel: RBFKernel
    log_alpha: float
    empty_var: float
    ll_dims: int
    gp_bound: float

    @classmethod
    def of(cls, d_x: int, d_y: int, params: RogerParams) -> ModelTerms:
        """The terms of a model with these (validated) dimensions and parameters."""
        scaling = AffineScaling(params, d_x, d_y)
        kernel = RBFKernel(params.theta_w, scaling.d_model, params.kernel_dim_scaling)
        dims = likelihood_dims(d_y, params.likelihood_normaliser)
        return cls(params=params, d_x=d_x, d_y=d_y, scaling=scaling, kernel=kernel,
                   log_alpha=math.log(params.alpha),
                   empty_var=kernel.k_star + params.theta_n, ll_dims=dims,
                   gp_bound=-0.5 * dims * math.log(2.0 * math.pi
                                                   * (params.theta_n + LATENT_FLOOR)))

    @property
    def d_model(self) -> int:
        """Input dimensions the gates and the kernel see (after ``input_weights``)."""
        return self.scaling.d_model

    def new_expert(self) -> SparseOnlineGP:
        """An empty expert of this model (:func:`new_expert`)."""
        return new_expert(self.params, self.d_model, self.d_y, self.kernel)

    def new_gates(self) -> GatePool:
        """An empty pool of this model's NIW gates (the prior ``mu0``, ``kappa0``,
        ``lambda0 I``, ``nu0``: ``d_x + 1`` unless set, :meth:`.RogerParams.nu0_for`)."""
        p = self.params
        return GatePool(self.d_model, p.mu0, p.kappa0, p.lambda0, p.nu0_for(self.d_x))
