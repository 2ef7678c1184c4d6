"""Learning one pair in several experts at once: one ROGER step's chosen experts.

:func:`update_many` is :meth:`.sogp.SparseOnlineGP.update` for each expert, but the experts on
the hot path (full: ``n = beta`` basis vectors in buffers for ``beta``) take the fused
add-then-delete step (:mod:`.sogp_fused`), one compiled call each.  Split from :mod:`.sogp`
(which re-exports it).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from roger_daemon.learner.sogp_fused import fused_add_delete as _fused_add_delete
from roger_daemon.learner.sogp_steps import NEAR_DEPENDENT as _NEAR_DEPENDENT

if TYPE_CHECKING:
    from roger_daemon.learner.sogp import SparseOnlineGP

__all__ = ["update_many"]

FloatArray = npt.NDArray[np.float64]

Terms = tuple[FloatArray, FloatArray, FloatArray, float]


def update_many(gps: Sequence[SparseOnlineGP], x: FloatArray, y: FloatArray,
                terms: Sequence[Terms | None]) -> None:
    """Learn the same pair in several distinct experts (one ROGER step's chosen experts).

    Equivalent to ``gp.update(x, y, t)`` for each (except that a non-novel point never
    re-inverts ``Q``: a projection update leaves ``Q`` unchanged).  The experts on the hot path
    (full, contiguous) are updated one after the other, each by ``Q k``, the novelty test and
    then one compiled fused add-then-delete step (:mod:`.sogp_fused`) or a projection update.
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
    kstar = full[0].kernel.k_star
    # one expert at a time, its Q k right before its own pass over Q (the step's other experts
    # would evict Q from the core's cache in between: docs/performance.md)
    for gp, t in zip(full, full_terms, strict=True):
        k, ck, mean, latent = t
        y_ext, mean = gp._targets(y, mean, k)  # with a prior mean, the a1 column too
        e_hat, gamma = gp.novelty(k)  # step 3
        gp.n_points += 1
        s0 = gp.noise
        if not gp.is_novel(gamma):  # step 4a for the non-novel few
            gp._sparse_update(ck, e_hat, gamma, -1.0 / (s0 + latent),
                              (y_ext - mean) / (s0 + latent))
            gp._clean_up()
        else:
            _fused_add_delete(gp, x, y_ext, ck, mean, latent, e_hat, gamma)
            gp._clean_up()
            if gamma < _NEAR_DEPENDENT * kstar and gp.n > 1:
                gp.refresh_inverse_gram()  # a 1/gamma-sized rank-1 term just entered Q
        gp._shift_mean(y)
