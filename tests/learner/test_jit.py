"""The compiled inner loops (roger_daemon/learner/engine/jit.py) against numpy oracles."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

from roger_daemon.learner.engine import jit_cholesky, jit_fused, jit_threads, packed
from roger_daemon.learner.engine import jit_kernels as jit
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
    cov = -_spd(n, rng)
    coef = rng.normal(size=(alloc, 3))
    x = rng.normal(size=4)
    k = kernel.gram(basis[:n], x[None])[:, 0]
    np.testing.assert_allclose(jit.kernel_vector(basis, x, kernel.gamma, n), k, rtol=1e-13)
    # C packed into a buffer for alloc basis vectors, its padding garbage that must not be read
    buf = np.full(packed.packed_size(alloc), np.nan)
    packed.pack_into(buf, alloc, cov, n)
    out = jit.expert_terms(basis, buf, coef, x, kernel.gamma, n, alloc)
    assert out.shape == (2 * n + 1 + 3,)
    ck = cov @ k
    np.testing.assert_allclose(out[:n], k, rtol=1e-13)
    np.testing.assert_allclose(out[n:2 * n], ck, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(out[2 * n], k @ ck, rtol=1e-12)
    np.testing.assert_allclose(out[2 * n + 1:], k @ coef[:n], rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("d", [1, 3, 23])
def test_a_kernel_value_does_not_depend_on_its_rows_place(d: int) -> None:
    """Each row's sum may be reassociated by LLVM, so every row must go through the one
    four-row code (:func:`jit_kernels.kernel_values`): the same value wherever the basis
    vector sits (first rows, a block, the last rows, fewer than four), in a kernel vector,
    in an expert's terms and in the Gram matrix of a re-inversion."""
    rng = np.random.default_rng(d)
    gamma = 0.3
    for n in range(1, 14):
        basis = rng.normal(size=(n, d))
        x = rng.normal(size=d)
        k = jit.kernel_vector(basis, x, gamma, n)
        for shift in (1, 2, 3, 5):
            moved = np.vstack([rng.normal(size=(shift, d)), basis])
            assert np.array_equal(jit.kernel_vector(moved, x, gamma, n + shift)[shift:], k)
        cov = np.zeros(packed.packed_size(n))
        assert np.array_equal(jit.expert_terms(basis, cov, np.zeros((n, 1)), x, gamma, n, n)[:n],
                              k)
        gram = jit.gram_matrix(basis, gamma, n)
        assert np.array_equal(gram, gram.T)
        for m in range(n):
            assert np.array_equal(gram[m], jit.kernel_vector(basis, basis[m].copy(), gamma, n))


def test_the_mean_skips_zero_kernel_values_bit_for_bit() -> None:
    """``k^T A`` in :func:`.jit_kernels.expert_terms` skips the rows whose kernel value is
    exactly zero: the same bits as the loop over every row compiled with the same flags (the
    oracle below), for kernel vectors with many zeros, some negative coefficients whose
    products are ``-0.0``, and an all-zero one."""
    from numba import njit

    @njit(fastmath={"reassoc", "contract"})
    def every_row(k: np.ndarray, coef: np.ndarray) -> np.ndarray:
        out = np.zeros(coef.shape[1])
        for i in range(k.shape[0]):
            for c in range(coef.shape[1]):
                out[c] += k[i] * coef[i, c]
        return out

    rng = np.random.default_rng(5)
    n, alloc, d = 60, 64, 3
    basis = rng.normal(size=(alloc, d)) * 4.0  # far apart: many kernel values underflow to 0
    coef = rng.normal(size=(alloc, 4))
    cov = np.zeros(packed.packed_size(alloc))
    zeros_seen = 0
    for x in [*rng.normal(size=(20, d)) * 4.0, np.full(d, 1e3)]:
        out = jit.expert_terms(basis, cov, coef, x, 40.0, n, alloc)
        k = out[:n]
        zeros_seen += int(np.sum(k == 0.0))
        want = every_row(k, coef[:n])
        assert out[2 * n + 1:].tobytes() == want.tobytes()
    assert zeros_seen > n  # the skip was exercised (the last input alone gives n zeros)


@pytest.mark.parametrize("n", [1, 2, 3, 5, 6, 7, 40, 300])
def test_sym_matvec_and_large_expert_terms_match_numpy(n: int) -> None:
    """Both compiled products also serve beta = 300 experts (no BLAS branch above 64 BVs);
    every count of rows left after the product's blocks of four (``n mod 4``), in buffers
    with NaN beyond the live block (read there, it would show)."""
    rng = np.random.default_rng(n + 7)
    alloc = n + 2
    mat = _spd(n, rng, cond=1e6)
    buf = np.full(packed.packed_size(alloc), np.nan)
    packed.pack_into(buf, alloc, mat, n)
    v = rng.normal(size=n)
    np.testing.assert_allclose(jit.sym_matvec(buf, v, n, alloc), mat @ v, rtol=1e-11,
                               atol=1e-13)
    for i in (0, n // 2, n - 1):
        np.testing.assert_array_equal(jit.sym_row(buf, alloc, n, i), np.triu(mat)[i]
                                      + np.triu(mat, 1)[:, i])
    kernel = RBFKernel(0.9, d_x=3)
    basis = rng.normal(size=(alloc, 3))
    coef = rng.normal(size=(alloc, 2))
    x = rng.normal(size=3)
    k = kernel.gram(basis[:n], x[None])[:, 0]
    out = jit.expert_terms(basis, -buf, coef, x, kernel.gamma, n, alloc)
    ck = -mat @ k
    np.testing.assert_allclose(out[n:2 * n], ck, rtol=1e-11, atol=1e-13)
    np.testing.assert_allclose(out[2 * n], k @ ck, rtol=1e-11, atol=1e-13)


def test_packing_round_trips_and_packed_add_lowrank_is_a_low_rank_term() -> None:
    rng = np.random.default_rng(3)
    n, alloc = 7, 10
    sym = rng.normal(size=(n, n))
    sym = sym + sym.T
    buf = packed.pack(sym, alloc)
    assert buf.shape == (alloc * (alloc + 1) // 2,)
    np.testing.assert_array_equal(packed.unpack(buf, alloc, n), sym)
    np.testing.assert_array_equal(packed.diagonal(buf, alloc, n), np.diagonal(sym))
    cols, coefs = rng.normal(size=(2, n)), np.array([0.5, -1.5])
    jit.packed_add_lowrank(buf, alloc, n, cols, coefs)
    np.testing.assert_allclose(packed.unpack(buf, alloc, n), sym + (cols.T * coefs) @ cols,
                               rtol=1e-13, atol=1e-13)


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
    cbuf, qbuf = packed.pack(c0, n), packed.pack(q0, n)
    dq = np.full(n, np.nan)
    jit_fused.rank_update_cq(cbuf, qbuf, n, n, i, uc, cc, uq, cq, dq)
    np.testing.assert_allclose(packed.unpack(cbuf, n, n), want_c, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(packed.unpack(qbuf, n, n), want_q, rtol=1e-13, atol=1e-13)
    # the diagonal it reports is the one stored, bit for bit
    assert np.array_equal(dq, packed.diagonal(qbuf, n, n))


@pytest.mark.parametrize("n", [1, 2, 8, 30])
def test_cholesky_inverse_matches_numpy_and_is_symmetric(n: int) -> None:
    rng = np.random.default_rng(n)
    gram = np.zeros((n + 2, n + 2))
    gram[:n, :n] = _spd(n, rng, cond=1e6)
    out = np.full((n + 2, n + 2), 7.0)
    assert jit_cholesky.cholesky_inverse(gram, n, 0.0, out)
    want = np.linalg.inv(gram[:n, :n])
    np.testing.assert_allclose(out[:n, :n], want, rtol=1e-8, atol=1e-8 * np.abs(want).max())
    np.testing.assert_array_equal(out[:n, :n], out[:n, :n].T)
    assert np.all(out[n:, :] == 7.0) and np.all(out[:, n:] == 7.0)  # padding untouched
    # with jitter: the inverse of K + jitter I
    assert jit_cholesky.cholesky_inverse(gram, n, 0.5, out)
    np.testing.assert_allclose(out[:n, :n], np.linalg.inv(gram[:n, :n] + 0.5 * np.eye(n)),
                               rtol=1e-10, atol=1e-12)


def _textbook_cholesky_inverse(gram: np.ndarray, n: int, jitter: float) -> tuple[float, np.ndarray]:
    """The oracle: ``L``, ``W = L^{-1}`` and ``W^T W`` as three plain triple loops, one sum at a
    time in index order (the kernel's code before it took four sums side by side)."""
    low = np.zeros((n, n))
    logdet = 0.0
    for j in range(n):
        s = gram[j, j] + jitter
        for p in range(j):
            s -= low[j, p] * low[j, p]
        d = math.sqrt(s)
        low[j, j] = d
        logdet += 2.0 * math.log(d)
        for r in range(j + 1, n):
            t = gram[r, j]
            for p in range(j):
                t -= low[r, p] * low[j, p]
            low[r, j] = t / d
    inv = np.zeros((n, n))
    for j in range(n):
        inv[j, j] = 1.0 / low[j, j]
        for r in range(j + 1, n):
            t = 0.0
            for p in range(j, r):
                t -= low[r, p] * inv[p, j]
            inv[r, j] = t / low[r, r]
    out = np.zeros((n, n))
    for a in range(n):
        for b in range(a + 1):
            t = 0.0
            for p in range(a, n):
                t += inv[p, a] * inv[p, b]
            out[a, b] = out[b, a] = t
    return logdet, out


@pytest.mark.parametrize("n", [1, 2, 3, 4, 5, 7, 8, 9, 23, 40])
def test_cholesky_inverse_gives_the_textbook_loops_bits(n: int) -> None:
    """Four sums side by side, each in the textbook loops' order: the very floats (every
    remainder of the blocks of four is reached by some ``n``), with and without jitter."""
    rng = np.random.default_rng(100 + n)
    gram = _spd(n, rng, cond=1e4)
    for jitter in (0.0, 0.25):
        out = np.empty((n, n))
        logdet = jit_cholesky.cholesky_inverse_logdet(gram, n, jitter, out)
        want_logdet, want = _textbook_cholesky_inverse(gram, n, jitter)
        assert logdet == want_logdet
        assert out.tobytes() == want.tobytes()


def test_cholesky_inverse_refuses_a_matrix_that_is_not_positive_definite() -> None:
    gram = np.array([[1.0, 2.0], [2.0, 1.0]])  # eigenvalues 3 and -1
    out = np.zeros((2, 2))
    assert not jit_cholesky.cholesky_inverse(gram, 2, 0.0, out)
    assert np.all(out == 0.0)
    assert jit_cholesky.cholesky_inverse(gram, 2, 1.5, out)  # + 1.5 I is SPD


def test_kernels_still_compile_where_no_cache_directory_is_writable() -> None:
    """numba refuses ``cache=True`` when it finds no writable cache location (a read-only
    install without a usable home); the kernels then compile without the on-disk cache."""
    code = ("import numba.core.caching as c\n"
            "c.CacheImpl._locator_classes = []\n"
            "import numpy as np\n"
            "from roger_daemon.learner.engine import jit_kernels as k\n"
            "assert type(k.kernel_vector._cache).__name__ == 'NullCache'\n"
            "print(k.kernel_vector(np.zeros((2, 1)), np.ones(1), 0.5, 2).tolist())\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, check=True)
    assert out.stdout.strip() == str([float(np.exp(-0.5))] * 2)


def test_trace_lineages_matches_the_python_pointer_chase() -> None:
    """Oracle: each lineage walked back in plain Python over random ancestor tables."""
    from roger_daemon.learner.engine.jit import trace_lineages

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


def test_fused_step_keeps_the_basis_and_the_diagonal_cache_consistent() -> None:
    """After compiled fused steps (issue 11): ``K_B`` recomputed from the basis is the Gram
    matrix of the basis vectors (numpy oracle) and the cached ``diag(C) + diag(Q)`` is the
    matrices' diagonal, up to round-off."""
    from roger_daemon.learner.sogp import SparseOnlineGP

    rng = np.random.default_rng(11)
    kernel = RBFKernel(0.5, d_x=3)
    gp = SparseOnlineGP(3, 2, kernel, noise=0.05, capacity=15)
    for _ in range(200):
        gp.update(rng.uniform(-1, 1, 3), rng.normal(size=2))
    assert gp.n == 15 and gp._dg is not None
    np.testing.assert_allclose(gp.gram, kernel.gram(gp.B, gp.B), rtol=1e-13)
    diag = np.diagonal(gp.C) + np.diagonal(gp.Q)
    np.testing.assert_allclose(gp._dg, diag, rtol=1e-8, atol=1e-10 * np.abs(diag).max())


def test_the_lazy_loader_binds_exactly_the_kernels_of_the_kernel_modules() -> None:
    """``jit.KERNELS`` (what ``roger_daemon.learner.engine.jit`` serves and ``warm_up``
    compiles) is the union of the kernel modules' exports, and each name resolves to that
    module's kernel; every engine module that compiles a kernel is one of them."""
    from pathlib import Path

    from roger_daemon.learner.engine import jit as lazy
    from roger_daemon.learner.engine import (
        jit_batch,
        jit_cholesky,
        jit_evaluate,
        jit_fused,
        jit_layout,
        jit_particles,
        jit_resampling,
        jit_small,
        jit_weights,
    )

    modules = (jit, jit_cholesky, jit_fused, jit_batch, jit_particles, jit_layout,
               jit_resampling, jit_small, jit_evaluate, jit_weights)
    folder = Path(lazy.__file__).parent
    compiling = {p.stem for p in folder.glob("*.py")
                 if "@_compiled(" in p.read_text() or "@compiled(" in p.read_text()}
    assert compiling == {m.__name__.rsplit(".", 1)[1] for m in modules}
    exports = [set(m.__all__) for m in modules]
    assert set(lazy.KERNELS) == set().union(*exports)
    assert sum(map(len, exports)) == len(set().union(*exports))  # no name in two modules
    for name in lazy.KERNELS:
        module = next(m for m in modules if name in m.__all__)
        assert getattr(lazy, name) is getattr(module, name)


@pytest.mark.parametrize("threads", [1, 2])
def test_warm_up_compiles_every_signature_a_learner_step_uses(
        threads: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """After ``warm_up`` nothing compiles inside a step (a first fused step on a full expert
    compiled its read-only-weights signature mid-run: seconds without numba's cache, in the
    daemon's first full learning step or in a timed benchmark), on one thread (the kernels
    called one expert at a time) and on two (batched)."""
    from roger_daemon.learner import Roger, RogerParams
    from roger_daemon.learner.engine.jit import compiled_signatures, set_threads, warm_up
    from roger_daemon.learner.synthetic import subtask_stream

    set_threads(threads)
    monkeypatch.setattr(jit_threads, "BATCH_MIN_ENTRIES", 0)  # these experts are small
    warm_up()
    before = compiled_signatures("roger_daemon.learner")
    s = subtask_stream(150)
    model = Roger(23, 9, RogerParams(beta=20), seed=5)
    for x, y in zip(s.x, s.y, strict=True):
        model.learn_one(x, y)
    model.predict_with_multimap(s.x[0])
    assert max(g.n for g in model.distinct_experts()) == 20  # the fused path ran
    assert compiled_signatures("roger_daemon.learner") == before


def test_learning_from_read_only_arrays_compiles_nothing_after_warm_up() -> None:
    """A read-only input (``np.frombuffer``, a memory map) is another array type to numba, so
    each kernel it reached would compile again mid-step; ``as_vector`` hands the learner a
    writable copy instead (with a prior mean, so that the targets' dot product runs too)."""
    from roger_daemon.learner import Roger, RogerParams
    from roger_daemon.learner.engine.jit import compiled_signatures, warm_up
    from roger_daemon.learner.synthetic import subtask_stream

    warm_up()
    before = compiled_signatures("roger_daemon.learner")
    s = subtask_stream(60)
    model = Roger(23, 9, RogerParams(beta=20, gp_prior_mean="expert"), seed=5)
    for x, y in zip(s.x, s.y, strict=True):
        rx, ry = np.frombuffer(x.tobytes()), np.frombuffer(y.tobytes())
        assert not rx.flags.writeable
        model.learn_one(rx, ry)
    model.predict_with_multimap(np.frombuffer(s.x[0].tobytes()))
    assert compiled_signatures("roger_daemon.learner") == before


@pytest.mark.parametrize("values", [
    [3.0], [1.0, 5.0, 5.0, -2.0], [0.0, -0.0, 0.0], [2.0, np.nan, 7.0, np.nan],
    [np.nan, 1.0], [-np.inf, np.inf, 4.0], list(np.random.default_rng(3).normal(size=301)),
])
def test_min_argmax_is_numpys_min_and_first_argmax(values: list[float]) -> None:
    """Oracle: ``np.min`` and ``np.argmax``, ties (the first maximum), signed zeros and NaN
    (minimum NaN, the first NaN the argmax) included."""
    v = np.array(values)
    got_min, got_arg = jit.min_argmax(v)
    assert got_arg == int(np.argmax(v))
    want = float(np.min(v))
    assert (np.isnan(got_min) and np.isnan(want)) or got_min == want


@pytest.mark.parametrize("n", [1, 7, 15])
def test_the_projection_update_is_numpys_bit_for_bit(n: int) -> None:
    """Oracle: the numpy projection update it replaced (``s = ck + e``, ``A += outer(s, q) *
    eta``, ``C += (r eta) s s^T`` by the packed low-rank kernel): the same floats exactly."""
    from roger_daemon.learner.engine import jit_kernels, jit_small
    from roger_daemon.learner.engine.packed import packed_size

    rng = np.random.default_rng(n)
    alloc = n + 3
    coef, cbuf = rng.normal(size=(alloc, 4)), rng.normal(size=packed_size(alloc))
    ck, e_hat, q = rng.normal(size=n), rng.normal(size=n), rng.normal(size=4)
    r, eta = -0.37, 1.0 / (1.0 - 0.2 * 0.37)
    want_a, want_c = coef.copy(), cbuf.copy()
    s_hat = ck + e_hat
    want_a[:n] += np.outer(s_hat, q) * eta
    jit_kernels.packed_add_lowrank(want_c, alloc, n, s_hat[None], np.array([r * eta]))
    jit_small.sparse_update(coef, cbuf, alloc, n, ck, e_hat, q, r, eta)
    assert np.array_equal(coef, want_a) and np.array_equal(cbuf, want_c)


@pytest.mark.parametrize("n", [1, 7, 15])
def test_the_prior_mean_shift_is_numpys_bit_for_bit(n: int) -> None:
    """Oracle: ``dm = (y - m) / n_points``, ``m + dm``, ``A[:n, :d] -= A[:n, d:d+1] * dm``
    in numpy: the same floats exactly, rows past ``n`` and the ``a1`` column untouched."""
    from roger_daemon.learner.engine import jit_small

    rng = np.random.default_rng(10 + n)
    d = 3
    coef, mean, y = rng.normal(size=(n + 2, d + 1)), rng.normal(size=d), rng.normal(size=d)
    want_a = coef.copy()
    dm = (y - mean) / 29
    want_m = mean + dm
    want_a[:n, :d] -= want_a[:n, d: d + 1] * dm
    out = np.empty(d)
    jit_small.shift_mean(coef, mean, y, n, 29, out)
    assert np.array_equal(out, want_m) and np.array_equal(coef, want_a)


@pytest.mark.parametrize("drift", [False, True])
def test_the_novelty_step_is_the_projection_test_and_drift_check(drift: bool) -> None:
    """Oracle: ``projection`` then ``novelty_test``, ``drifted`` or'ed with ``min diag(Q) k* <
    1 - tol`` (``SOGPSteps.q_drifted``): the same floats and decisions."""
    from roger_daemon.learner.engine import jit_kernels, jit_small
    from roger_daemon.learner.engine.packed import diagonal, pack

    rng = np.random.default_rng(4)
    n, alloc, kstar = 9, 12, 1.0
    m = rng.normal(size=(n, n))
    q = 0.01 * m @ m.T / n + np.eye(n) * (0.5 if drift else 1.5)  # diag(Q) < 1/k*: drifted
    qbuf, k = pack(q, alloc), rng.uniform(0, 0.2, n)  # k^T Q k < k*: gamma > 0
    e_want, kqk = jit_kernels.projection(qbuf, k, n, alloc)
    g_want, d_want, n_want = jit_kernels.novelty_test(kqk, kstar, 1e-3, 1e-12, 1e-6)
    d_want = d_want or bool(diagonal(qbuf, alloc, n).min() * kstar < 1.0 - 1e-6)
    e_hat, gamma, drifted, novel = jit_small.novelty_step(qbuf, k, n, alloc, kstar, 1e-3,
                                                          1e-12, 1e-6)
    assert np.array_equal(e_hat, e_want) and gamma == g_want
    assert (drifted, novel) == (d_want, n_want) and drifted == drift


def test_the_reinversion_is_the_gram_cholesky_and_packing_it_replaced() -> None:
    """Oracle: ``gram_matrix``, ``cholesky_inverse`` and ``packed.pack_into``, as the separate
    calls made them: the same floats; a failed factorisation leaves ``Q`` untouched."""
    from roger_daemon.learner.engine import jit_kernels, jit_small
    from roger_daemon.learner.engine.packed import pack_into, packed_size

    rng = np.random.default_rng(6)
    n, alloc, gamma = 11, 14, 0.7
    basis = rng.normal(size=(alloc, 4))
    want, got = np.zeros(packed_size(alloc)), np.zeros(packed_size(alloc))
    inverse = np.empty((n, n))
    assert jit_cholesky.cholesky_inverse(jit_kernels.gram_matrix(basis, gamma, n), n, 0.0,
                                        inverse)
    pack_into(want, alloc, inverse, n)
    assert jit_small.refresh_inverse(basis, gamma, n, 0.0, got, alloc)
    assert np.array_equal(got, want)
    twin = basis.copy()
    twin[1] = twin[0]  # two equal basis vectors: K_B is singular
    before = got.copy()
    assert not jit_small.refresh_inverse(twin, gamma, 2, -1.0, got, alloc)
    assert np.array_equal(got, before)


@pytest.mark.parametrize("prior_mean", [True, False])
def test_the_batched_prediction_is_each_experts_own_bit_for_bit(prior_mean: bool) -> None:
    """Oracle: ``SparseOnlineGP.predict`` of each expert on its own. ``predict_many`` (one
    compiled call per ``EVALUATION_WIDTH`` experts) gives the same means and variances, to the
    bit, for more experts than one call takes, of different sizes, an input far from every
    basis vector, and an expert with no basis vector (its prior)."""
    from roger_daemon.learner.engine.jit import EVALUATION_WIDTH
    from roger_daemon.learner.sogp import SparseOnlineGP
    from roger_daemon.learner.sogp_batch import predict_many

    rng = np.random.default_rng(11)
    d_x, d_y = 4, 3
    gps = []
    for j in range(EVALUATION_WIDTH + 5):
        gp = SparseOnlineGP(d_x, d_y, RBFKernel(0.5, d_x), noise=0.05, capacity=12,
                            prior_mean=prior_mean)
        for _ in range(1 + j % 17):  # 1 to 17 points: some experts full, some deleting
            gp.update(rng.normal(size=d_x), rng.normal(size=d_y))
        gps.append(gp)
    queries = [rng.normal(size=d_x) for _ in range(20)] + [np.full(d_x, 50.0)]
    for group in (gps, gps[:3]):
        for x in queries:
            means, variance = np.empty((len(group), d_y)), np.empty(len(group))
            predict_many(group, x, means, variance)
            for j, gp in enumerate(group):
                mean, var = gp.predict(x)
                assert np.array_equal(means[j], mean) and variance[j] == var
    empty = SparseOnlineGP(d_x, d_y, RBFKernel(0.5, d_x), noise=0.05, capacity=12,
                           prior_mean=prior_mean)
    group = [gps[0], empty]
    means, variance = np.empty((2, d_y)), np.empty(2)
    predict_many(group, queries[0], means, variance)
    for j, gp in enumerate(group):
        mean, var = gp.predict(queries[0])
        assert np.array_equal(means[j], mean) and variance[j] == var


@pytest.mark.parametrize("n", [0, 1, 9, 40])
def test_dot_column_sums_in_index_order(n: int) -> None:
    """Oracle: the same products and additions in Python floats, one after the other (IEEE
    operations: the same bits); a column of a wider matrix, and a vector as a one-column
    view (the empty expert's ``|y|^2``)."""
    from roger_daemon.learner.engine import jit_small

    rng = np.random.default_rng(n)
    k, coef = rng.normal(size=n + 2), rng.normal(size=(n + 2, 3))
    want = 0.0
    for i in range(n):
        want += float(k[i]) * float(coef[i, 2])
    assert jit_small.dot_column(k, coef, 2, n) == want
    square = 0.0
    for v in k[:n].tolist():
        square += v * v
    y = k[:n].copy()
    assert jit_small.dot_column(y, y.reshape(-1, 1), 0, n) == square
