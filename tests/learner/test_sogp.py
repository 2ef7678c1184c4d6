"""Sparse online GP: exactness oracle, capacity, deletion quality, fused hot path."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from roger_daemon.learner.kernel import RBFKernel
from roger_daemon.learner.sogp import SparseOnlineGP, gaussian_log_likelihood
from roger_daemon.learner.sogp_batch import update_many


def exact_gp(xtr: np.ndarray, ytr: np.ndarray, xte: np.ndarray, width: float, noise: float,
             ) -> tuple[np.ndarray, np.ndarray]:
    """Batch GP regression written out independently (Rasmussen & Williams Alg. 2.1)."""
    def k(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        d2 = ((a[:, None, :] - b[None, :, :]) ** 2).sum(-1)
        return np.exp(-d2 / (2 * width**2))

    kxx = k(xtr, xtr) + noise * np.eye(len(xtr))
    chol = np.linalg.cholesky(kxx)
    alpha = np.linalg.solve(chol.T, np.linalg.solve(chol, ytr))
    ks = k(xte, xtr)
    mean = ks @ alpha
    v = np.linalg.solve(chol, ks.T)
    var = 1.0 - (v * v).sum(0) + noise
    return mean, var


def make_gp(d_x: int, d_y: int, width: float = 0.5, noise: float = 0.1,
            capacity: int | None = None, threshold: float = 0.0) -> SparseOnlineGP:
    return SparseOnlineGP(d_x, d_y, RBFKernel(width, d_x), noise, capacity, threshold)


@pytest.mark.parametrize(("d_x", "d_y"), [(1, 1), (3, 2), (23, 9)])
def test_unbudgeted_sogp_equals_exact_gp(d_x: int, d_y: int) -> None:
    rng = np.random.default_rng(1)
    n = 20 if d_x == 1 else 60
    x = rng.uniform(-1, 1, (n, d_x))
    y = np.sin(3 * x[:, :1]) + 0.1 * rng.normal(size=(n, d_y))
    width = 0.7 if d_x > 1 else 0.1  # keeps K well conditioned (Q = K^-1 is tracked)
    gp = make_gp(d_x, d_y, width=width, noise=0.05)
    for xi, yi in zip(x, y, strict=True):
        gp.update(xi, yi)
    assert gp.n == n  # every point a full update
    xte = rng.uniform(-1.2, 1.2, (25, d_x))
    mean_ref, var_ref = exact_gp(x, y, xte, width, 0.05)
    for j, xt in enumerate(xte):
        mean, var = gp.predict(xt)
        np.testing.assert_allclose(mean, mean_ref[j], atol=1e-8)
        assert abs(var - var_ref[j]) < 1e-8


def test_unbudgeted_state_matches_closed_form() -> None:
    """A = (K + s0 I)^-1 Y, C = -(K + s0 I)^-1, Q = K^-1 (docs/learner-math.md §2.8)."""
    rng = np.random.default_rng(2)
    x = rng.uniform(-1, 1, (20, 2))
    y = rng.normal(size=(20, 3))
    gp = make_gp(2, 3, width=0.6, noise=0.1)
    for xi, yi in zip(x, y, strict=True):
        gp.update(xi, yi)
    kmat = gp.kernel.gram(x, x)
    inv = np.linalg.inv(kmat + 0.1 * np.eye(20))
    np.testing.assert_allclose(gp.A, inv @ y, atol=1e-8)
    np.testing.assert_allclose(gp.C, -inv, atol=1e-8)
    np.testing.assert_allclose(gp.Q, np.linalg.inv(kmat), rtol=1e-6, atol=1e-6)


@given(capacity=st.integers(1, 25), n=st.integers(1, 80), seed=st.integers(0, 2**16))
@settings(max_examples=40, deadline=None)
def test_capacity_never_exceeded(capacity: int, n: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    gp = make_gp(2, 2, width=0.3, capacity=capacity, threshold=1e-6)
    for _ in range(n):
        gp.update(rng.uniform(-1, 1, 2), rng.normal(size=2))
        assert gp.n <= capacity
        c, q = gp.C, gp.Q
        assert np.all(np.isfinite(c)) and np.all(np.isfinite(q))
        np.testing.assert_allclose(c, c.T, atol=1e-9 * max(1.0, np.abs(c).max()))
        np.testing.assert_allclose(q, q.T, atol=1e-9 * max(1.0, np.abs(q).max()))
    assert gp.n_points == n


def test_deletion_keeps_predictions_close_to_exact_gp() -> None:
    """On smooth 1-D data 12 BVs out of 300 points predict like the exact GP."""
    rng = np.random.default_rng(3)
    x = rng.uniform(0, 1, (300, 1))
    y = np.cos(5 * x) + 0.05 * rng.normal(size=(300, 1))
    gp = make_gp(1, 1, width=0.15, noise=0.01, capacity=12, threshold=1e-6)
    deletions = 0
    for xi, yi in zip(x, y, strict=True):
        before = gp.n
        gp.update(xi, yi)
        deletions += gp.n == before == 12
    assert gp.n == 12 and deletions > 50
    xte = np.linspace(0.05, 0.95, 50)[:, None]
    mean_ref, var_ref = exact_gp(x, y, xte, 0.15, 0.01)
    mean = np.array([gp.predict(xt)[0][0] for xt in xte])
    var = np.array([gp.predict(xt)[1] for xt in xte])
    assert np.max(np.abs(mean - mean_ref[:, 0])) < 0.03
    assert np.mean((mean - np.cos(5 * xte[:, 0])) ** 2) < 1e-3  # Grollman's cos(5x) check
    assert np.max(np.abs(var - var_ref)) < 0.01


def test_bv_count_reaches_capacity_and_falls_with_width() -> None:
    """Grollman's test program: #BV == capacity; fewer BVs for wider kernels."""
    x = (np.arange(400) * 0.6180339887498949 % 1.0)[:, None]  # low discrepancy: no near-twins
    counts = []
    for width in (0.004, 0.05, 0.5):
        gp = make_gp(1, 1, width=width, noise=0.01, capacity=100, threshold=1e-6)
        for xi in x:
            gp.update(xi, np.cos(5 * xi))
        counts.append(gp.n)
    assert counts[0] == 100
    assert counts[0] >= counts[1] >= counts[2]
    assert counts[2] < counts[0]


@pytest.mark.parametrize(("d_x", "width"), [(1, 0.2), (5, 0.6)])
def test_fused_update_delete_equals_two_step_reference(d_x: int, width: float) -> None:
    """One fused add+delete step == full update then KL deletion, from the same state."""
    rng = np.random.default_rng(5)
    gp = make_gp(d_x, 3, width=width, capacity=12, threshold=1e-6)
    steps = 0
    for _ in range(300):
        x = rng.uniform(-1, 1, d_x)
        y = rng.normal(size=3)
        ref = gp.copy()
        ref.fused = False
        gp.update(x, y)
        ref.update(x, y)
        if ref.n != 12:
            continue
        steps += 1
        # same basis set, possibly in another order
        order_gp = np.lexsort(gp.B.T)
        order_ref = np.lexsort(ref.B.T)
        np.testing.assert_array_equal(gp.B[order_gp], ref.B[order_ref])
        ix = np.ix_(order_gp, order_gp)
        ir = np.ix_(order_ref, order_ref)
        for mine, theirs in ((gp.C[ix], ref.C[ir]), (gp.Q[ix], ref.Q[ir])):
            np.testing.assert_allclose(mine, theirs, rtol=1e-9, atol=1e-9 * np.abs(theirs).max())
        np.testing.assert_allclose(gp.A[order_gp], ref.A[order_ref], rtol=1e-9, atol=1e-9)
    assert steps > 100


def test_sparse_update_when_not_novel() -> None:
    gp = make_gp(1, 1, width=0.5, capacity=10, threshold=1e-6)
    gp.update(np.array([0.2]), np.array([1.0]))
    gp.update(np.array([0.2]), np.array([1.2]))  # same input: projection update
    assert gp.n == 1 and gp.n_points == 2
    mean, var = gp.predict(np.array([0.2]))
    # two noisy observations of the same latent value: exact posterior
    mean_ref, var_ref = exact_gp(np.array([[0.2], [0.2 + 1e-9]]), np.array([[1.0], [1.2]]),
                                 np.array([[0.2]]), 0.5, 0.1)
    assert abs(mean[0] - mean_ref[0, 0]) < 1e-6
    assert abs(var - var_ref[0]) < 1e-6


def test_empty_expert_predicts_prior_and_copy_is_independent() -> None:
    gp = make_gp(2, 2, noise=0.1, capacity=5)
    mean, var = gp.predict(np.zeros(2))
    assert np.all(mean == 0) and var == pytest.approx(1.1)
    gp.update(np.zeros(2), np.ones(2))
    twin = gp.copy()
    twin.update(np.ones(2), -np.ones(2))
    assert gp.n == 1 and twin.n == 2 and gp.n_points == 1


def test_log_likelihood_normalisers() -> None:
    # multivariate: -(d/2) log(2 pi s2) - |e|^2 / (2 s2); grollman: the 1-D constant
    ll = float(gaussian_log_likelihood(0.5, 0.2, 9))
    assert ll == pytest.approx(-4.5 * np.log(2 * np.pi * 0.2) - 0.5 / 0.4)
    ll1 = float(gaussian_log_likelihood(0.5, 0.2, 9, "grollman"))
    assert ll1 == pytest.approx(-0.5 * np.log(2 * np.pi) - 0.5 * np.log(0.2) - 0.5 / 0.4)
    gp = make_gp(2, 3, noise=0.1, capacity=5)
    y = np.array([0.1, -0.2, 0.3])
    from scipy.stats import multivariate_normal
    ref = multivariate_normal(np.zeros(3), 1.1 * np.eye(3)).logpdf(y)
    assert gp.log_likelihood(np.zeros(2), y) == pytest.approx(ref)


def test_update_many_equals_one_by_one() -> None:
    """The batched step == each expert's own update (full, growing and empty experts mixed)."""
    rng = np.random.default_rng(6)
    experts = []
    for n_seed in (40, 40, 5, 0, 60):
        gp = make_gp(3, 2, width=0.5, capacity=12, threshold=1e-6)
        for _ in range(n_seed):
            gp.update(rng.uniform(-1, 1, 3), rng.normal(size=2))
        experts.append(gp)
    twins = [g.copy() for g in experts]
    for _ in range(30):
        x, y = rng.uniform(-1, 1, 3), rng.normal(size=2)
        update_many(experts, x, y, [g.terms(x) for g in experts])
        for t in twins:
            t.update(x, y)
        for g, t in zip(experts, twins, strict=True):
            assert g.n == t.n and g.n_points == t.n_points
            np.testing.assert_array_equal(g.B, t.B)
            np.testing.assert_allclose(g.A, t.A, rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(g.C, t.C, rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(g.Q, t.Q, rtol=1e-12, atol=1e-12)


def test_hot_path_diagonal_cache_tracks_the_matrices() -> None:
    rng = np.random.default_rng(7)
    gp = make_gp(4, 2, width=0.5, capacity=15, threshold=1e-6)
    for _ in range(300):
        gp.update(rng.uniform(-1, 1, 4), rng.normal(size=2))
    assert gp._dg is not None  # the fused path ran and left its cache
    truth = np.diagonal(gp.C) + np.diagonal(gp.Q)
    np.testing.assert_allclose(gp._dg, truth, rtol=1e-9, atol=1e-9 * np.abs(truth).max())
    # Q stays the inverse Gram matrix of the basis (drift bounded)
    gram = gp.kernel.gram(gp.B, gp.B)
    np.testing.assert_allclose(gp.Q @ gram, np.eye(gp.n), atol=1e-6)


def test_cached_diagonal_of_q_is_the_stored_one_bit_for_bit() -> None:
    """The fused step's copy of ``diag(Q)`` (read by the drift check and the clean-up) equals
    the diagonal stored in ``Q`` after every step: fused steps, re-inversions on
    near-duplicate inputs, projection updates and copies (an exact cache: same decisions)."""
    rng = np.random.default_rng(11)
    t = np.linspace(0, 8, 500)
    x = np.stack([np.sin(t), np.cos(1.3 * t), 0.5 * np.sin(0.7 * t)], 1)
    x += 1e-3 * rng.normal(size=x.shape)
    y = np.stack([np.sin(2 * t), np.cos(t)], 1)
    gps = [make_gp(3, 2, width=w, noise=0.1, capacity=20, threshold=1e-4) for w in (0.3, 1.0)]
    cached = 0
    for i, (xi, yi) in enumerate(zip(x, y, strict=True)):
        update_many(gps, xi, yi, [g.terms(xi) for g in gps])
        if i % 50 == 49:
            gps = [g.copy() for g in gps]
        for g in gps:
            stored = np.diagonal(g.Q)
            assert np.array_equal(g._diag_q(), stored)
            if g._dq is not None:
                cached += 1
                assert np.array_equal(g._dq, stored)
                assert g._dq_min == stored.min() and g._dq_argmax == int(np.argmax(stored))
    assert cached > 100 and sum(g.q_refreshes for g in gps) > 0


def test_inverse_gram_stays_consistent_on_near_duplicate_inputs() -> None:
    """Consecutive robot frames are near-duplicates: with a broad kernel K_B gets very
    ill-conditioned and the rank-1-updated Q drifts from K_B^-1 (docs/learner-math.md §7, pitfall 6)
    unless it is re-inverted (measured: max |Q K_B - I| 77 without, 3e-4 with)."""
    rng = np.random.default_rng(3)
    t = np.linspace(0, 6, 600)
    x = np.stack([np.sin(t), np.cos(1.3 * t), 0.5 * np.sin(0.7 * t)], 1)
    x += 1e-3 * rng.normal(size=x.shape)
    y = np.stack([np.sin(2 * t), np.cos(t)], 1)
    gp = make_gp(3, 2, width=1.0, noise=0.1, capacity=40, threshold=1e-6)
    worst = 0.0
    for xi, yi in zip(x, y, strict=True):
        gp.update(xi, yi)
        if gp.n > 1:
            gram = gp.kernel.gram(gp.B, gp.B)
            worst = max(worst, float(np.abs(gp.Q @ gram - np.eye(gp.n)).max()))
    assert gp.q_refreshes > 0
    assert worst < 1e-3
    copy = gp.copy()
    assert copy.q_refreshes == gp.q_refreshes
