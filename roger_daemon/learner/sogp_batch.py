"""Learning one pair in several experts at once: one ROGER step's chosen experts.

:func:`update_many` is :meth:`.sogp.SparseOnlineGP.update` for each expert, but the experts on
the hot path (full, contiguous, ``x`` novel) share one batched fused add-then-delete step
(:mod:`.sogp_fused`).  Split from :mod:`.sogp` (which re-exports it).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from roger_daemon.learner import jit as _jit
from roger_daemon.learner.sogp_fused import fused_add_delete as _fused_add_delete
from roger_daemon.learner.sogp_steps import GAMMA_FLOOR as _GAMMA_FLOOR
from roger_daemon.learner.sogp_steps import NEAR_DEPENDENT as _NEAR_DEPENDENT

if TYPE_CHECKING:
    from roger_daemon.learner.sogp import SparseOnlineGP

__all__ = ["update_many"]

FloatArray = npt.NDArray[np.float64]

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
    e_hat = np.stack([_jit.matvec(gp._Q, k, gp.n)  # step 3: Q k
                      for gp, k in zip(full, ks, strict=True)])
    gamma = kstar - np.einsum("un,un->u", ks, e_hat)
    for j, gp in enumerate(full):
        if gp.q_inconsistent(float(gamma[j])):
            gp.refresh_inverse_gram()
            e_hat[j] = _jit.matvec(gp._Q, ks[j], gp.n)
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
