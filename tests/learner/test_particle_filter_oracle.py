"""An exact oracle for the particle filter itself (paper Algorithm 1, docs/learner-math.md §4).

With at least as many particles as there are set partitions of the points (Bell(N)), no
putative is ever dropped, so after N points the particles are exactly the partitions of the N
points and each one's weight is its posterior probability.  With novelty threshold 0 and room
for every point, each expert's sparse GP is the exact GP (§2.8), so that posterior is, by the
chain rule over the points in order,

    p(z | x, y) ∝ prod_i CRP(z_i | z_<i) t(x_i | earlier x of its block) N(y_i | GP of its block)

computed here by brute force over every set partition, with scipy's Student-t and the GP's
closed form, independently of the learners' code.  Checked on the reference learner (particle
by particle) and on the fast one (its particles in the same order, and as a set), to 1e-9.
"""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.special import logsumexp
from scipy.stats import multivariate_t

from roger_daemon.learner import Roger, RogerParams
from roger_daemon.learner.reference import ReferenceRoger

TOL = 1e-9

Partition = tuple[int, ...]


def partitions(n: int) -> Iterator[Partition]:
    """Every set partition of ``range(n)`` as a restricted growth string (block labels in
    order of first appearance)."""
    def grow(prefix: list[int], top: int) -> Iterator[Partition]:
        if len(prefix) == n:
            yield tuple(prefix)
            return
        for label in range(top + 2):
            yield from grow([*prefix, label], max(top, label))

    yield from grow([], -1)


def canonical(ids: np.ndarray) -> Partition:
    """Expert ids relabelled in order of first appearance."""
    seen: dict[int, int] = {}
    return tuple(seen.setdefault(int(i), len(seen)) for i in ids)


def log_crp(z: Partition, alpha: float, kappa: float) -> float:
    """The (sticky) CRP prior of the labels, point by point: ``(n_k + kappa [k = z_(i-1)]) /
    (i + alpha + kappa)``, ``alpha / (i + alpha + kappa)`` for a new block (kappa after the
    first point only)."""
    out = 0.0
    for i, k in enumerate(z):
        n_k = z[:i].count(k)
        stick = kappa if i > 0 else 0.0
        num = alpha if n_k == 0 else n_k + (stick if z[i - 1] == k else 0.0)
        out += math.log(num) - math.log(i + alpha + stick)
    return out


def log_gate(x: np.ndarray, earlier: np.ndarray, p: RogerParams) -> float:
    """``log t(x | earlier)``: the NIW posterior predictive after the batch update (§3.1)."""
    d, n = x.size, len(earlier)
    mu0 = np.full(d, p.mu0)
    lam = p.lambda0 * np.eye(d)
    mu, kappa, nu = mu0, p.kappa0, p.nu0
    if n:
        xbar = earlier.mean(axis=0)
        lam = lam + (earlier - xbar).T @ (earlier - xbar) \
            + (p.kappa0 * n / (p.kappa0 + n)) * np.outer(xbar - mu0, xbar - mu0)
        mu, kappa, nu = (p.kappa0 * mu0 + n * xbar) / (p.kappa0 + n), p.kappa0 + n, p.nu0 + n
    df = nu - d + 1
    return float(multivariate_t(loc=mu, shape=lam * (kappa + 1) / (kappa * df), df=df).logpdf(x))


def log_gp(x: np.ndarray, y: np.ndarray, bx: np.ndarray, by: np.ndarray,
           p: RogerParams) -> float:
    """``log N(y | the exact GP of the block's earlier points)`` (§2.4, §2.8; prior mean §8)."""
    s0 = p.theta_n
    m = by.mean(axis=0) if p.gp_prior_mean == "expert" and len(by) else np.zeros(y.size)
    mean, var = m, 1.0 + s0
    if len(bx):
        def kern(a: np.ndarray, b: np.ndarray) -> np.ndarray:
            return np.exp(-np.sum((a[:, None] - b[None]) ** 2, axis=2) / (2 * p.theta_w**2))

        gram = kern(bx, bx) + s0 * np.eye(len(bx))
        k = kern(bx, x[None])[:, 0]
        mean = m + k @ np.linalg.solve(gram, by - m)
        var = 1.0 + s0 - k @ np.linalg.solve(gram, k)
    dims = y.size if p.likelihood_normaliser == "multivariate" else 1
    return -0.5 * dims * math.log(2 * math.pi * var) - float((y - mean) @ (y - mean)) / (2 * var)


def exact_posterior(x: np.ndarray, y: np.ndarray, p: RogerParams) -> dict[Partition, float]:
    """``log p(z | x, y)`` of every partition ``z`` of the points, by the chain rule."""
    out = {}
    for z in partitions(len(x)):
        total = log_crp(z, p.alpha, p.sticky_kappa)
        for i, k in enumerate(z):
            block = [j for j in range(i) if z[j] == k]
            total += log_gate(x[i], x[block], p) + log_gp(x[i], y[i], x[block], y[block], p)
        out[z] = total
    norm = logsumexp(list(out.values()))
    return {z: v - norm for z, v in out.items()}


def bell(n: int) -> int:
    return sum(1 for _ in partitions(n))


def params(n: int, **changes: object) -> RogerParams:
    """Exact experts (threshold 0, room for every point) and a particle per partition."""
    base = {"alpha": 0.7, "kappa0": 0.5, "lambda0": 0.5, "nu0": 3.0, "theta_w": 0.6,
            "theta_n": 0.05, "novelty_threshold": 0.0, "beta": 10, "particles": bell(n)}
    return RogerParams.from_mapping({**base, **changes})


def check(x: np.ndarray, y: np.ndarray, p: RogerParams, seed: int = 0) -> None:
    exact = exact_posterior(x, y, p)
    ref = ReferenceRoger(x.shape[1], y.shape[1], p, seed=seed)
    fast = Roger(x.shape[1], y.shape[1], p, seed=seed)
    for xi, yi in zip(x, y, strict=True):
        ref.learn_one(xi, yi)
        fast.learn_one(xi, yi)
    assert ref.stats["projections"] == 0 and ref.stats["draws"] == 0  # the premises
    # the reference: one particle per partition, each with its exact posterior weight
    got = {canonical(ref.particle_assignments(i)): w
           for i, w in enumerate(ref.particle_log_weights().tolist())}
    assert got.keys() == exact.keys()
    np.testing.assert_allclose([got[z] for z in exact], list(exact.values()), rtol=0, atol=TOL)
    # the fast learner: the same weights in the same particle order, and as a set
    lw = fast.particle_log_weights()
    np.testing.assert_allclose(lw, ref.particle_log_weights(), rtol=0, atol=TOL)
    np.testing.assert_allclose(np.sort(lw), np.sort(list(exact.values())), rtol=0, atol=TOL)
    best = max(exact, key=exact.__getitem__)
    assert canonical(fast.assignments()) == canonical(ref.assignments()) == best


def stream(n: int, d_x: int, d_y: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    x = rng.uniform(-1.0, 1.0, (n, d_x))
    sign = np.where(rng.uniform(size=(n, 1)) < 0.5, 1.0, -1.0)  # two branches
    return x, sign * np.sin(2.0 * x[:, :d_y]) + 0.05 * rng.normal(size=(n, d_y))


def test_partitions_are_counted_by_the_bell_numbers() -> None:
    assert [bell(n) for n in range(1, 7)] == [1, 2, 5, 15, 52, 203]
    assert len(set(partitions(5))) == 52


@pytest.mark.parametrize("changes", [
    {},
    {"sticky_kappa": 1.5},
    {"gp_prior_mean": "expert"},
    {"likelihood_normaliser": "grollman", "alpha": 2.0, "mu0": 0.3},
], ids=["paper", "sticky", "prior mean", "normaliser and priors"])
def test_the_particle_weights_are_the_exact_posterior_over_partitions(
        changes: dict[str, object]) -> None:
    """Six points, 203 particles: all the partitions, each with its exact weight."""
    x, y = stream(6, 2, 2, seed=3)
    check(x, y, params(6, **changes))


@given(n=st.integers(2, 5), d_x=st.integers(1, 3), seed=st.integers(0, 10_000),
       alpha=st.floats(0.1, 3.0), kappa=st.sampled_from([0.0, 0.5, 3.0]))
@settings(max_examples=25, deadline=None)
def test_the_exact_posterior_on_generated_streams(n: int, d_x: int, seed: int, alpha: float,
                                                   kappa: float) -> None:
    x, y = stream(n, d_x, 1, seed)
    check(x, y, params(n, alpha=alpha, sticky_kappa=kappa, nu0=float(d_x) + 1.0), seed)
