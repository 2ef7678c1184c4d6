"""The compiled inner loops (roger_daemon/learner/jit.py) against numpy oracles."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from roger_daemon.learner import jit_kernels as jit
from roger_daemon.learner.kernel import RBFKernel


def _spd(n: int, rng: np.random.Generator, cond: float = 1e3) -> np.ndarray:
    q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    return (q * np.geomspace(1.0, 1.0 / cond, n)) @ q.T


@pytest.mark.parametrize("n", [1, 5, 40])
def test_kernel_vector_and_expert_terms_match_numpy(n: int) -> None:
    rng = np.random.default_rng(n)
    kernel = RBFKernel(0.7, d_x=4)
    alloc = n + 3  # live block inside a larger buffer, as in an expert
    basis = rng.normal(size=(alloc, 4))
    cov = np.zeros((alloc, alloc))
    cov[:n, :n] = -_spd(n, rng)
    coef = rng.normal(size=(alloc, 3))
    x = rng.normal(size=4)
    k = kernel.gram(basis[:n], x[None])[:, 0]
    np.testing.assert_allclose(jit.kernel_vector(basis, x, kernel.gamma, n), k, rtol=1e-13)
    packed = jit.expert_terms(basis, cov, coef, x, kernel.gamma, n)
    assert packed.shape == (2 * n + 1 + 3,)
    ck = cov[:n, :n] @ k
    np.testing.assert_allclose(packed[:n], k, rtol=1e-13)
    np.testing.assert_allclose(packed[n:2 * n], ck, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(packed[2 * n], k @ ck, rtol=1e-12)
    np.testing.assert_allclose(packed[2 * n + 1:], k @ coef[:n], rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("n", [1, 40, 300])
def test_matvec_and_large_expert_terms_match_numpy(n: int) -> None:
    """Both compiled products also serve beta = 300 experts (no BLAS branch above 64 BVs)."""
    rng = np.random.default_rng(n + 7)
    alloc = n + 2
    mat = np.zeros((alloc, alloc))
    mat[:n, :n] = _spd(n, rng, cond=1e6)
    v = rng.normal(size=n)
    np.testing.assert_allclose(jit.matvec(mat, v, n), mat[:n, :n] @ v, rtol=1e-11, atol=1e-13)
    kernel = RBFKernel(0.9, d_x=3)
    basis = rng.normal(size=(alloc, 3))
    coef = rng.normal(size=(alloc, 2))
    x = rng.normal(size=3)
    k = kernel.gram(basis[:n], x[None])[:, 0]
    packed = jit.expert_terms(basis, -mat, coef, x, kernel.gamma, n)
    ck = -mat[:n, :n] @ k
    np.testing.assert_allclose(packed[n:2 * n], ck, rtol=1e-11, atol=1e-13)
    np.testing.assert_allclose(packed[2 * n], k @ ck, rtol=1e-11, atol=1e-13)


@pytest.mark.parametrize("i", [-1, 0, 6])
def test_rank_update_cq_is_zeroing_then_two_low_rank_terms(i: int) -> None:
    rng = np.random.default_rng(7)
    n = 9
    c0, q0 = rng.normal(size=(n, n)), rng.normal(size=(n, n))
    c0, q0 = c0 + c0.T, q0 + q0.T
    uc, cc = rng.normal(size=(3, n)), np.array([0.5, -2.0, 1.5])
    uq, cq = rng.normal(size=(2, n)), np.array([3.0, -0.25])
    want_c, want_q = c0.copy(), q0.copy()
    if i >= 0:
        for m in (want_c, want_q):
            m[i, :] = 0.0
            m[:, i] = 0.0
    want_c += (uc.T * cc) @ uc
    want_q += (uq.T * cq) @ uq
    cmat, qmat = c0.copy(), q0.copy()
    jit.rank_update_cq(cmat, qmat, n, i, uc, cc, uq, cq)
    np.testing.assert_allclose(cmat, want_c, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(qmat, want_q, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(cmat, cmat.T, rtol=0, atol=1e-13)  # symmetric up to round-off


@pytest.mark.parametrize("n", [1, 2, 8, 30])
def test_cholesky_inverse_matches_numpy_and_is_symmetric(n: int) -> None:
    rng = np.random.default_rng(n)
    gram = np.zeros((n + 2, n + 2))
    gram[:n, :n] = _spd(n, rng, cond=1e6)
    out = np.full((n + 2, n + 2), 7.0)
    assert jit.cholesky_inverse(gram, n, 0.0, out)
    want = np.linalg.inv(gram[:n, :n])
    np.testing.assert_allclose(out[:n, :n], want, rtol=1e-8, atol=1e-8 * np.abs(want).max())
    np.testing.assert_array_equal(out[:n, :n], out[:n, :n].T)
    assert np.all(out[n:, :] == 7.0) and np.all(out[:, n:] == 7.0)  # padding untouched
    # with jitter: the inverse of K + jitter I
    assert jit.cholesky_inverse(gram, n, 0.5, out)
    np.testing.assert_allclose(out[:n, :n], np.linalg.inv(gram[:n, :n] + 0.5 * np.eye(n)),
                               rtol=1e-10, atol=1e-12)


def test_cholesky_inverse_refuses_a_matrix_that_is_not_positive_definite() -> None:
    gram = np.array([[1.0, 2.0], [2.0, 1.0]])  # eigenvalues 3 and -1
    out = np.zeros((2, 2))
    assert not jit.cholesky_inverse(gram, 2, 0.0, out)
    assert np.all(out == 0.0)
    assert jit.cholesky_inverse(gram, 2, 1.5, out)  # + 1.5 I is SPD


def test_kernels_still_compile_where_no_cache_directory_is_writable() -> None:
    """numba refuses ``cache=True`` when it finds no writable cache location (a read-only
    install without a usable home); the kernels then compile without the on-disk cache."""
    code = ("import numba.core.caching as c\n"
            "c.CacheImpl._locator_classes = []\n"
            "import numpy as np\n"
            "from roger_daemon.learner import jit_kernels as k\n"
            "assert type(k.kernel_vector._cache).__name__ == 'NullCache'\n"
            "print(k.kernel_vector(np.zeros((2, 1)), np.ones(1), 0.5, 2).tolist())\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, check=True)
    assert out.stdout.strip() == str([float(np.exp(-0.5))] * 2)


def test_trace_lineages_matches_the_python_pointer_chase() -> None:
    """Oracle: each lineage walked back in plain Python over random ancestor tables."""
    from roger_daemon.learner.jit import trace_lineages

    rng = np.random.default_rng(7)
    for n, width in ((1, 1), (5, 3), (200, 30)):
        anc = rng.integers(0, width, size=(n + 4, width)).astype(np.int32)
        eid = rng.integers(0, 50, size=(n + 4, width)).astype(np.int64)
        starts = rng.integers(0, width, 3).astype(np.int64)
        ids, origin = trace_lineages(anc, eid, n, starts)
        assert ids.dtype == np.int64 and ids.shape == (n, 3)
        for s, last in enumerate(starts.tolist()):
            expected, j = [0] * n, last
            for t in range(n - 1, -1, -1):
                expected[t] = int(eid[t, j])
                j = int(anc[t, j])
            np.testing.assert_array_equal(ids[:, s], expected)
            assert origin[s] == j


def test_fused_step_keeps_the_gram_matrix_and_the_diagonal_cache_consistent() -> None:
    """After compiled fused steps (issue 11): ``K_B`` is the Gram matrix of the basis and the
    cached ``diag(C) + diag(Q)`` is the matrices' diagonal, up to round-off."""
    from roger_daemon.learner.sogp import SparseOnlineGP

    rng = np.random.default_rng(11)
    kernel = RBFKernel(0.5, d_x=3)
    gp = SparseOnlineGP(3, 2, kernel, noise=0.05, capacity=15)
    for _ in range(200):
        gp.update(rng.uniform(-1, 1, 3), rng.normal(size=2))
    assert gp.n == 15 and gp._dg is not None
    np.testing.assert_allclose(gp._K[:15, :15], kernel.gram(gp.B, gp.B), rtol=1e-13)
    diag = np.diagonal(gp.C) + np.diagonal(gp.Q)
    np.testing.assert_allclose(gp._dg, diag, rtol=1e-8, atol=1e-10 * np.abs(diag).max())
