"""NIW gates: Student-t predictive against scipy, order invariance, batched pool."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import multivariate_t

from roger_daemon.learner.engine.gates import GatePool
from roger_daemon.learner.engine.jit_scalar import student_t_normaliser
from roger_daemon.learner.gate import NIWGate, niw_update


def test_prior_predictive_matches_scipy_and_paper_values() -> None:
    """Paper values, d = 23: nu_t = 2 and Sigma_t = 5.5 I (docs/learner-math.md §3.3)."""
    gate = NIWGate(23, 0.0, 0.1, 1.0, 24.0)
    df, loc, shape = gate.predictive()
    assert df == 2.0
    np.testing.assert_allclose(shape, 5.5 * np.eye(23))
    x = np.random.default_rng(0).normal(size=(5, 23))
    ref = multivariate_t(loc=loc, shape=shape, df=df).logpdf(x)
    np.testing.assert_allclose(gate.log_predictive(x), ref, rtol=1e-12)


@given(d=st.integers(1, 6), n=st.integers(0, 30), seed=st.integers(0, 2**16))
@settings(max_examples=50, deadline=None)
def test_posterior_predictive_matches_scipy(d: int, n: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    gate = NIWGate(d, 0.3, 0.5, 2.0, d + 1.5)
    data = rng.normal(1.0, 2.0, (n, d))
    for x in data:
        gate.update(x)
    df, loc, shape = gate.predictive()
    q = rng.normal(0.0, 3.0, (4, d))
    ref = multivariate_t(loc=loc, shape=shape, df=df).logpdf(q)
    np.testing.assert_allclose(gate.log_predictive(q), np.atleast_1d(ref), rtol=1e-9, atol=1e-9)


def test_batch_posterior_formula() -> None:
    """Rank-1 recursion == batch NIW posterior (docs/learner-math.md §3.1)."""
    rng = np.random.default_rng(1)
    data = rng.normal(5.0, 1.0, (40, 3))  # offset data: no catastrophic cancellation
    gate = NIWGate(3, 0.0, 0.1, 1.0, 4.0)
    for x in data:
        gate.update(x)
    n = 40
    xbar = data.mean(0)
    scatter = (data - xbar).T @ (data - xbar)
    lam = np.eye(3) + scatter + (0.1 * n / (0.1 + n)) * np.outer(xbar, xbar)
    assert gate.kappa == pytest.approx(40.1) and gate.nu == 44.0
    np.testing.assert_allclose(gate.mu, n * xbar / 40.1, rtol=1e-12)
    np.testing.assert_allclose(gate.lam, lam, rtol=1e-10)


@given(perm_seed=st.integers(0, 2**16), n=st.integers(1, 25))
@settings(max_examples=50, deadline=None)
def test_updates_in_any_order_give_the_same_posterior(perm_seed: int, n: int) -> None:
    rng = np.random.default_rng(perm_seed)
    data = rng.normal(0.0, 1.0, (n, 4))
    a = NIWGate(4, 0.0, 0.1, 1.0, 5.0)
    b = NIWGate(4, 0.0, 0.1, 1.0, 5.0)
    for x in data:
        a.update(x)
    for x in data[rng.permutation(n)]:
        b.update(x)
    assert a.kappa == b.kappa and a.nu == b.nu
    np.testing.assert_allclose(a.mu, b.mu, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(a.lam, b.lam, rtol=1e-11, atol=1e-11)
    q = rng.normal(size=(3, 4))
    np.testing.assert_allclose(a.log_predictive(q), b.log_predictive(q), rtol=1e-10)


def test_pool_batches_many_gates() -> None:
    rng = np.random.default_rng(2)
    pool = GatePool(3, 0.0, 0.1, 1.0, 4.0, capacity=2)
    gates = []
    for slot in range(7):
        pool.grow(slot + 1)
        x0 = rng.normal(size=3)
        pool.set_prior_updated(slot, x0)
        g = NIWGate(3, 0.0, 0.1, 1.0, 4.0)
        g.update(x0)
        for _ in range(slot * 3):
            x = rng.normal(slot, 1.0, 3)
            pool.update(slot, x)
            g.update(x)
        gates.append(g)
    q = rng.normal(size=3)
    slots = np.array([6, 0, 3, 3])
    got = pool.log_predictive(slots, q)
    want = [gates[s].log_predictive(q)[0] for s in slots]
    np.testing.assert_allclose(got, want, rtol=1e-10)
    pool.grow(8)
    pool.copy_slot(7, 2)
    assert pool.log_predictive(np.array([7]), q)[0] == pool.log_predictive(np.array([2]), q)[0]
    assert pool.prior_log_predictive(q) == pytest.approx(
        float(NIWGate(3, 0.0, 0.1, 1.0, 4.0).log_predictive(q)[0]))


def test_batched_update_of_many_slots_matches_the_niw_recursion_and_scipy() -> None:
    """The compiled batched update (several slots, one input each step) against the rank-1
    NIW recursion per gate, the exact inverse and determinant, and scipy's Student-t."""
    d = 4
    rng = np.random.default_rng(11)
    pool = GatePool(d, 0.0, 0.1, 1.0, 6.0, capacity=5)
    slots = np.array([0, 2, 4], dtype=np.int64)
    for s in range(5):
        pool.set_prior(s)
    ref = {int(s): (0.1, 6.0, np.zeros(d), np.eye(d)) for s in slots}
    for _ in range(40):  # crosses the every-32-updates recomputation
        x = rng.normal(size=d)
        pool.update_many(slots, x)
        ref = {s: niw_update(*v, x) for s, v in ref.items()}
    q = rng.normal(size=d)
    got = pool.log_predictive(slots, q)
    for j, s in enumerate(slots.tolist()):
        kappa, nu, mu, lam = ref[s]
        np.testing.assert_allclose(pool.mu[s], mu, rtol=1e-12)
        np.testing.assert_allclose(pool.lam[s], lam, rtol=1e-12)
        np.testing.assert_allclose(pool.prec[s], np.linalg.inv(lam), rtol=1e-8, atol=1e-12)
        assert pool.logdet[s] == pytest.approx(np.linalg.slogdet(lam)[1], rel=1e-10)
        df = nu - d + 1.0
        want = multivariate_t(loc=mu, shape=lam * (kappa + 1.0) / (kappa * df),
                                    df=df).logpdf(q)
        assert got[j] == pytest.approx(want, rel=1e-9)
    assert pool.count[1] == 0 and pool.kappa[1] == 0.1  # untouched slot


def test_the_compiled_student_t_constants_are_pythons_to_round_off() -> None:
    """One formula (jit_scalar.student_t_normaliser), run by Python for the prior and compiled
    for the gates' updates: numba's ``lgamma`` is not CPython's, so the log normaliser agrees
    to round-off; the other two constants are bit for bit."""
    from roger_daemon.learner.engine import jit_particles

    rng = np.random.default_rng(5)
    for d in (1, 3, 23):
        for _ in range(300):
            kappa = float(rng.uniform(0.01, 1e4))
            nu = d + float(rng.uniform(0.0, 1e5))
            logdet = float(rng.normal(0.0, 50.0))
            lognorm, half, inv = student_t_normaliser(kappa, nu, logdet, d)
            got = jit_particles.gate_constants(kappa, nu, logdet, d)
            # the two lgamma terms are up to ~1e6 and cancel: a few of their ulps
            nu_t = nu - d + 1.0
            scale = abs(math.lgamma((nu_t + d) / 2.0)) + abs(math.lgamma(nu_t / 2.0)) + 1.0
            assert got[0] == pytest.approx(lognorm, rel=0.0, abs=1e-15 * scale)
            assert got[1:] == (half, inv)


def test_the_update_recomputes_the_constants_of_the_gates_it_updates() -> None:
    """After updates (and the every-32 recomputation), each updated slot's cached Student-t
    constants are the compiled formula's for its kappa, nu and log|Lambda|, bit for bit; the
    others keep the prior's (Python's)."""
    from roger_daemon.learner.engine import jit_particles

    d = 3
    rng = np.random.default_rng(6)
    pool = GatePool(d, 0.0, 0.1, 1.0, 5.0, capacity=4)
    for s in range(4):
        pool.set_prior(s)
    slots = np.array([1, 3], dtype=np.int64)
    prior = (pool.lognorm[0], pool.half_nu_d[0], pool.inv_nu_c[0])
    assert prior == student_t_normaliser(0.1, 5.0, 0.0, d)  # log|I| = 0
    for _ in range(33):
        pool.update_many(slots, rng.normal(size=d))
        for s in (1, 3):
            want = jit_particles.gate_constants(pool.kappa[s], pool.nu[s], pool.logdet[s], d)
            assert (pool.lognorm[s], pool.half_nu_d[s], pool.inv_nu_c[s]) == want
        for s in (0, 2):
            assert (pool.lognorm[s], pool.half_nu_d[s], pool.inv_nu_c[s]) == prior
    assert pool.count.tolist() == [0, 33, 0, 33]


@pytest.mark.parametrize("d", [1, 3, 23])
def test_the_compiled_precision_is_the_inverse_and_log_determinant(d: int) -> None:
    """:func:`.jit_cholesky.cholesky_inverse_logdet` (the gates' every-32 recomputation, no
    LAPACK) against numpy's inverse and ``slogdet``: equal to round-off, ``prec`` exactly
    symmetric; a matrix that is not positive definite leaves ``prec`` as it was and gives
    NaN."""
    from roger_daemon.learner.engine import jit_cholesky

    rng = np.random.default_rng(d)
    m = rng.normal(size=(d, d + 4))
    lam = m @ m.T + 0.1 * np.eye(d)
    prec = np.empty((d, d))
    logdet = jit_cholesky.cholesky_inverse_logdet(lam, d, 0.0, prec)
    np.testing.assert_allclose(prec, np.linalg.inv(lam), rtol=1e-10, atol=1e-12)
    assert logdet == pytest.approx(np.linalg.slogdet(lam)[1], rel=1e-12, abs=1e-12)
    assert np.array_equal(prec, prec.T)
    before = prec.copy()
    singular = lam.copy()
    singular[-1, -1] = -1.0  # a negative last pivot
    assert np.isnan(jit_cholesky.cholesky_inverse_logdet(singular, d, 0.0, prec))
    assert np.array_equal(prec, before)


def test_every_32nd_update_recomputes_the_precision_from_lambda() -> None:
    """At a gate's 32nd input its precision and ``log|Lambda|`` are
    :func:`.jit_cholesky.cholesky_inverse_logdet`'s of its ``Lambda``, bit for bit (before it,
    the Sherman-Morrison ones, which differ in the last bits)."""
    from roger_daemon.learner.engine import jit_cholesky

    d = 4
    rng = np.random.default_rng(11)
    pool = GatePool(d, 0.0, 0.1, 1.0, 6.0, capacity=2)
    pool.set_prior(0)
    slots = np.zeros(1, dtype=np.int64)
    for i in range(1, 33):
        pool.update_many(slots, rng.normal(size=d))
        fresh = np.empty((d, d))
        logdet = jit_cholesky.cholesky_inverse_logdet(pool.lam[0], d, 0.0, fresh)
        if i == 31:
            assert not np.array_equal(pool.prec[0], fresh)
    assert pool.count[0] == 32
    assert np.array_equal(pool.prec[0], fresh) and pool.logdet[0] == logdet
