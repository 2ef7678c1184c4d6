"""The sparse online GP's hot path: "add a basis vector, then delete one" in one pass.

With continuous data nearly every point is novel, so a full expert (``n = beta``) adds a
basis vector and deletes one at every step (docs/learner-math.md §2.5 steps 4b and 5, §2.7).
:func:`fused_add_delete` does both as one rank-3 update of ``C`` and one rank-2 update of ``Q``,
in place on the packed ``C`` and ``Q`` (:mod:`.packed`) by one compiled call, for each expert
a ROGER step updates (:func:`.sogp.update_many`, one expert after the other).  Split from
:mod:`.sogp`, whose private buffers it updates; numerically it is
:meth:`~.sogp.SparseOnlineGP._full_update` then :meth:`~.sogp.SparseOnlineGP.delete` up to
round-off (tested).
"""

from __future__ import annotations

from functools import lru_cache
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from roger_daemon.learner import jit as _jit

if TYPE_CHECKING:
    from roger_daemon.learner.sogp import SparseOnlineGP

__all__ = ["fused_add_delete", "output_weights"]

FloatArray = npt.NDArray[np.float64]


def fused_add_delete(gp: SparseOnlineGP, x: FloatArray, y: FloatArray, ck: FloatArray,
                     mean: FloatArray, latent: float, e_hat: FloatArray,
                     gamma: float) -> None:
    """Full update to n + 1 BVs then one KL-optimal deletion of one full expert, in place.

    ``ck``, ``mean``, ``latent`` are the expert's terms at ``x`` (with a prior mean,
    ``y`` and ``mean`` extended by the ``a1`` column), ``e_hat = Q k`` and ``gamma`` the
    novelty (docs/learner-math.md §2.5 step 3).

    With ``s = [Ck; 1]`` and ``e = [Q k; -1]`` the (n+1)-BV state would be
    ``C1 = C (+) 0 + r s s^T``, ``Q1 = Q (+) 0 + e e^T / gamma``, ``A1 = A (+) 0 + s q^T``
    (docs/learner-math.md §2.5 step 4b).  Deleting BV ``i`` (§2.7) needs only column ``i`` and the
    diagonals of ``C1`` and ``Q1``, which are O(n) from ``C``, ``Q``, ``s`` and ``e``.  The new
    BV takes the place of ``i``, so with ``q_v``, ``c_v`` the columns of ``Q1``, ``C1`` at
    ``i`` and ``w = q_v + c_v`` (all permuted so that index n sits at i)::

        C2 = C_z + [s, q_v, w] diag(r, 1/q*, -1/(q* + c*)) [s, q_v, w]^T
        Q2 = Q_z + [e, q_v] diag(1/gamma, -1/q*) [e, q_v]^T
        A2 = A1 - w a*^T / (q* + c*)

    (``C_z``: ``C`` with row and column ``i`` zeroed): one rank-3 and one rank-2 in-place
    update instead of five passes.  The whole step (scores, vectors, ``A``, ``B``, the diagonal
    cache and the one pass over ``C`` and ``Q``) is one compiled call,
    :func:`.jit_fused.fused_step` (the numpy version batched over experts spent ~0.35 ms
    per ROGER step in ~60 small array calls at beta = 300, issue 11).
    Equal to :meth:`SparseOnlineGP._full_update` then :meth:`SparseOnlineGP.delete` up to
    round-off (tested).  ``n_points`` is not touched.
    """
    denom = gp.noise + latent
    r = -1.0 / denom  # Csató's K2
    q = (y - mean) / denom  # Csató's K1
    gp._dg, gp._dq, gp._dq_min, gp._dq_argmax = _jit.fused_step(
        gp._B, gp._A, gp._Cp, gp._Qp, gp._diag_cq(), x, ck, e_hat,
        output_weights(gp.a_cols, gp.d_y), q, r, gamma)


@lru_cache(maxsize=8)
def output_weights(a_cols: int, d_y: int) -> FloatArray:
    """1 for the output columns of ``A``, 0 for a prior mean's ``a1`` column: the deletion
    scores count the outputs only (read-only)."""
    cw = np.ones(a_cols)
    cw[d_y:] = 0.0
    cw.setflags(write=False)
    return cw
