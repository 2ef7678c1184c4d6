"""An expert that is not full learns by one compiled call (:func:`.jit_small.growth_step`):
the same floats, bit for bit, as the numpy and kernel calls it replaced (step 4b's among
them, :func:`.jit_small.add_basis_vector`, as numpy calls)."""

from __future__ import annotations

from collections import Counter
from typing import Any

import numpy as np
import pytest

from roger_daemon.learner.engine import jit, packed
from roger_daemon.learner.kernel import RBFKernel
from roger_daemon.learner.sogp import SparseOnlineGP


def _full_update_numpy(gp: SparseOnlineGP, x: np.ndarray, ck: np.ndarray, e_hat: np.ndarray,
                       gamma: float, r: float, q: np.ndarray) -> None:
    """Step 4b as numpy calls, the code before :func:`.jit_small.add_basis_vector`: ``x``
    becomes basis vector ``n`` (the buffers grown first), ``A += s q^T``, ``C += r s s^T``,
    ``Q += e e^T / gamma`` with ``s = [C k; 1]``, ``e = [Q k; -1]``."""
    n = gp.n
    gp._forget_diagonals()
    gp._grow(n + 1)
    gp._B[n] = x
    s = np.append(ck, 1.0)
    gp._A[n] = 0.0
    gp._A[: n + 1] += np.outer(s, q)
    e = np.append(e_hat, -1.0)
    column = packed.row_offsets(gp.alloc)[: n + 1] + (n - np.arange(n + 1))
    for buf in (gp._Cp, gp._Qp):
        buf[column] = 0.0  # row and column n (stale padding after a deletion)
    jit.packed_add_lowrank(gp._Cp, gp.alloc, n + 1, s[None], np.array([r]))
    jit.packed_add_lowrank(gp._Qp, gp.alloc, n + 1, e[None], np.array([1.0 / gamma]))
    gp.n = n + 1


def _update_by_separate_calls(gp: SparseOnlineGP, x: np.ndarray, y: np.ndarray) -> None:
    """The oracle: :meth:`.sogp.SparseOnlineGP.update` of an expert with ``n >= 1`` basis
    vectors that is not full, as it was before ``growth_step``: the novelty test (``Q``
    re-inverted if it drifted), the projection or full update (numpy's), the clean-up, the
    end."""
    gp.n_points += 1
    gp._forget_diagonals()
    k, ck, mean, latent = gp.terms(x)
    y, mean = gp.targets(y, mean, k)
    r = -1.0 / (gp.noise + latent)
    q = (y - mean) / (gp.noise + latent)
    e_hat, gamma, novel = gp.novelty(k)
    if novel:
        _full_update_numpy(gp, x, ck, e_hat, gamma, r, q)
    else:
        gp._sparse_update(ck, e_hat, gamma, r, q)
    gp._clean_up()
    gp._after_update(gamma, y)


def _live(gp: SparseOnlineGP) -> list[np.ndarray]:
    return [gp.B, gp.A, gp.C, gp.Q, gp.mean_offset]


@pytest.mark.parametrize(("width", "threshold", "d_x", "prior_mean", "capacity"), [
    (2.0, 1e-8, 1, False, 40),  # every outcome: adds, projects, needs room, Q drifts, cleans up
    (2.0, 1e-8, 1, True, 40),
    (1.0, 1e-3, 2, False, 40),
    (1.0, 1e-3, 2, True, 12),  # full, without the fused step: buffers for beta + 1, step 5
])
def test_a_growing_expert_learns_the_same_bits_as_by_separate_calls(
        width: float, threshold: float, d_x: int, prior_mean: bool, capacity: int,
        monkeypatch: pytest.MonkeyPatch) -> None:
    jit.warm_up()
    outcomes: Counter[Any] = Counter()
    compiled = jit.growth_step

    def counted(*args: Any) -> tuple[int, float, bool]:
        out: tuple[int, float, bool] = compiled(*args)
        outcomes[out[0]] += 1
        if out[0] in (jit.ADDED, jit.PROJECTED):
            outcomes["cleaned up"] += not out[2]
        return out

    monkeypatch.setattr(jit, "growth_step", counted)
    rng = np.random.default_rng(7)
    new = SparseOnlineGP(d_x, 2, RBFKernel(width, d_x), 0.3, capacity, threshold,
                         prior_mean=prior_mean)
    new.fused = capacity == 40  # the same path either way below beta
    old = new.copy()
    for i in range(300):
        x = rng.uniform(-1.0, 1.0, d_x)
        y = np.array([np.sin(3.0 * x.sum()), np.cos(x.sum())])
        new.update(x, y)
        if old.n == 0:
            old.update(x, y)
        else:
            _update_by_separate_calls(old, x, y)
        assert (new.n, new.n_points, new.q_refreshes) == (old.n, old.n_points, old.q_refreshes)
        assert new.novelty_margin == old.novelty_margin, i
        for got, want in zip(_live(new), _live(old), strict=True):
            assert np.array_equal(got, want), i
    # never full, or full without the fused step: every step took growth_step first
    assert new.n < capacity or not new.fused
    want = {jit.ADDED, jit.PROJECTED}
    if capacity == 12:
        want |= {jit.NEEDS_ROOM}
    if width == 2.0:
        want |= {jit.NEEDS_ROOM, jit.DRIFTED, "cleaned up"}
    assert want <= {key for key, count in outcomes.items() if count}, outcomes
