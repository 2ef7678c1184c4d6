"""The issue-13 levers, each against an exact oracle or a property; all off = the paper.

* ``gp_prior_mean="expert"``: a GP whose prior mean is m equals a zero-mean GP on ``y - m``;
  the running mean is the mean of the outputs assigned to the expert;
* ``sticky_kappa``: every putative log weight equals a brute-force sticky-CRP formula (kappa = 0
  is the paper's CRP); ``kappa = inf`` keeps every point with its predecessor's expert;
* ``min_support``: prediction-only, gate probabilities renormalised over supported experts;
* ``input_weights``: a weight-0 dimension is invisible, a weight w equals multiplying the data;
* presets and state migration.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.stats import multivariate_t

from roger_daemon.learner import ParameterError, Roger, RogerParams, UnimapGP, load_model
from roger_daemon.learner.kernel import RBFKernel
from roger_daemon.learner.params import PRESETS
from roger_daemon.learner.roger_step import putatives
from roger_daemon.learner.sogp import SparseOnlineGP, gaussian_log_likelihood
from roger_daemon.learner.sogp_batch import update_many
from roger_daemon.learner.synthetic import sqrt_multimap, subtask_stream

from .states import with_schema


def learn(model: Roger | UnimapGP, x: np.ndarray, y: np.ndarray) -> None:
    for xi, yi in zip(x, y, strict=True):
        model.learn_one(xi, yi)


def gp(d_x: int, d_y: int, *, width: float = 0.7, noise: float = 0.05,
       capacity: int | None = None, threshold: float = 0.0,
       prior_mean: bool = False) -> SparseOnlineGP:
    return SparseOnlineGP(d_x, d_y, RBFKernel(width, d_x), noise, capacity, threshold,
                          prior_mean=prior_mean)


def data(n: int, d_x: int, d_y: int, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    x = rng.uniform(-1, 1, (n, d_x))
    y = 2.0 + np.sin(3 * x[:, :1]) + 0.1 * rng.normal(size=(n, d_y))  # mean far from 0
    return x, y


# -- a. per-expert GP prior mean --------------------------------------------------------------


@pytest.mark.parametrize(("d_x", "d_y"), [(1, 1), (3, 2)])
def test_prior_mean_equals_exact_gp_with_that_mean(d_x: int, d_y: int) -> None:
    """Unbudgeted, every point a basis vector: mean = m + k^T (K + s^2 I)^-1 (Y - 1 m^T)."""
    x, y = data(30, d_x, d_y)
    width = 0.1 if d_x == 1 else 0.7  # K well conditioned (as in test_sogp)
    model, zero = (gp(d_x, d_y, width=width, prior_mean=pm) for pm in (True, False))
    for xi, yi in zip(x, y, strict=True):
        model.update(xi, yi)
        zero.update(xi, yi)
    m = y.mean(axis=0)
    np.testing.assert_allclose(model.mean_offset, m, rtol=1e-13)
    kern = RBFKernel(width, d_x)
    kxx = kern.gram(x, x) + 0.05 * np.eye(len(x))
    coef = np.linalg.solve(kxx, y - m)
    for xt in np.random.default_rng(2).uniform(-3, 3, (20, d_x)):
        mean, var = model.predict(xt)
        np.testing.assert_allclose(mean, m + kern(x, xt) @ coef, atol=1e-8)
        assert abs(var - zero.predict(xt)[1]) < 1e-10  # variance unchanged in form
    far = np.full(d_x, 50.0)  # far from the data: the expert's mean action, not 0
    np.testing.assert_allclose(model.predict(far)[0], m, rtol=1e-12)
    np.testing.assert_allclose(zero.predict(far)[0], 0.0, atol=1e-300)


def test_prior_mean_with_projections_equals_zero_mean_gp_on_centred_targets() -> None:
    """Sparse (projection) updates too: the prediction is m_N + the zero-mean SOGP trained
    on y_i - m_N, since which points become basis vectors depends on x alone."""
    x, y = data(120, 2, 3, seed=4)
    model = gp(2, 3, width=0.6, threshold=0.05, prior_mean=True)
    for xi, yi in zip(x, y, strict=True):
        model.update(xi, yi)
    m = model.mean_offset
    ref = gp(2, 3, width=0.6, threshold=0.05)
    for xi, yi in zip(x, y, strict=True):
        ref.update(xi, yi - m)
    assert 0 < model.n == ref.n < len(x)  # some points were projected
    for xt in np.random.default_rng(3).uniform(-2, 2, (20, 2)):
        np.testing.assert_allclose(model.predict(xt)[0], m + ref.predict(xt)[0], atol=1e-9)
        assert model.predict(xt)[1] == ref.predict(xt)[1]


def test_prior_mean_on_a_budget_fused_equals_two_step_and_constant_data_is_exact() -> None:
    x, y = data(200, 3, 2, seed=6)
    fused = gp(3, 2, width=0.5, capacity=12, threshold=1e-6, prior_mean=True)
    plain = fused.copy()
    plain.fused = False
    batch = [fused.copy() for _ in range(2)]
    for xi, yi in zip(x, y, strict=True):
        fused.update(xi, yi)
        plain.update(xi, yi)
        update_many(batch, xi, yi, [None, None])
    assert fused.n == 12
    for xt in x[:10]:
        np.testing.assert_allclose(fused.predict(xt)[0], plain.predict(xt)[0], atol=1e-9)
        np.testing.assert_allclose(batch[0].predict(xt)[0], fused.predict(xt)[0], atol=1e-12)
    np.testing.assert_allclose(fused.mean_offset, y.mean(axis=0), rtol=1e-12)
    # constant outputs: the centred GP learns 0, the prediction is that constant everywhere
    const = gp(3, 2, width=0.5, capacity=12, threshold=1e-6, prior_mean=True)
    for xi in x:
        const.update(xi, np.array([0.75, -1.5]))
    for xt in np.random.default_rng(0).uniform(-5, 5, (10, 3)):
        np.testing.assert_allclose(const.predict(xt)[0], [0.75, -1.5], atol=1e-12)


def test_roger_expert_means_are_the_means_of_their_assigned_outputs() -> None:
    """No labels: each expert's prior mean is the mean of the y assigned to it (MAP particle);
    far from all data an expert predicts it (the zero-mean model predicts 0)."""
    s = subtask_stream(250)
    model = Roger(23, 9, RogerParams(beta=25, gp_prior_mean="expert", theta_w=1.0), seed=2)
    learn(model, s.x, s.y)
    assign = model.assignments()
    far = np.full(23, 1e3)
    for branch in model.predict_multimap(far):
        mine = s.y[assign == branch.expert_id]
        assert len(mine) == branch.n_points
        np.testing.assert_allclose(branch.mean, mine.mean(axis=0), rtol=1e-9, atol=1e-12)
    zero = Roger(23, 9, RogerParams(beta=25, theta_w=1.0), seed=2)
    learn(zero, s.x, s.y)
    np.testing.assert_array_equal(zero.predict_one(far).mean, np.zeros(9))


# -- c. sticky partition prior ----------------------------------------------------------------


def reference_log_weights(model: Roger, xs: np.ndarray, ys: np.ndarray) -> list[np.ndarray]:
    """Putative log weights from the model's public pieces and scipy, per particle:
    log w_p + log(n_k + kappa [k = previous expert]) + log t_k(x) + log N(y; mu_k, s_k^2 I)."""
    p = model.params
    sd = model.state_dict()
    prev = sd["history_expert"][-1]
    offsets = sd["particle_offsets"]
    out = []
    prior_t = multivariate_t(np.full(len(xs), p.mu0), np.eye(len(xs)) * p.lambda0
                             * (p.kappa0 + 1) / (p.kappa0 * (p.nu0 - len(xs) + 1)),
                             df=p.nu0 - len(xs) + 1)
    for j, w in enumerate(model.particle_log_weights()):
        row = []
        slot_of = {int(model.store.ids[s]): s for s in model.particle_slots(j).tolist()}
        for idx in sd["particle_experts"][offsets[j]:offsets[j + 1]]:
            eid = int(sd["expert_id"][idx])
            n_k = float(sd["expert_count"][idx])
            s = slot_of[eid]
            df, loc, shape = model.store.gates.predictive(s)
            g = model.store.expert(s)
            mean, var = g.predict(xs)
            crp = n_k + (p.sticky_kappa if eid == prev[j] else 0.0)
            row.append(w + math.log(crp) + multivariate_t(loc, shape, df=df).logpdf(xs)
                       + float(gaussian_log_likelihood(float((ys - mean) @ (ys - mean)), var,
                                                       len(ys))))
        row.append(w + math.log(p.alpha) + prior_t.logpdf(xs) + float(
            gaussian_log_likelihood(float(ys @ ys), 1.0 + p.theta_n, len(ys))))
        out.append(np.array(row))
    return out


@pytest.mark.parametrize("kappa", [0.0, 3.0, 40.0])
def test_putative_weights_are_the_sticky_crp_formula(kappa: float) -> None:
    s = sqrt_multimap(60, seed=1)
    model = Roger(1, 1, RogerParams(beta=20, theta_n=0.01, nu0=3.0, sticky_kappa=kappa), seed=4)
    learn(model, s.x[:-1], s.y[:-1])
    assert model.n_experts >= 2
    xs, ys = s.x[-1], s.y[-1]
    put = putatives(model.store, model.terms, model.history, xs, ys)
    lw, flat_part = put.log_weights, put.parent
    ref = reference_log_weights(model, xs, ys)
    for j, row in enumerate(ref):
        mine = lw[flat_part == j]
        np.testing.assert_allclose(mine, row, rtol=1e-10, atol=1e-9)


def test_kappa_zero_is_the_paper_bit_for_bit() -> None:
    s = subtask_stream(150)
    a = Roger(23, 9, RogerParams(beta=20), seed=5)
    b = Roger(23, 9, RogerParams(beta=20, sticky_kappa=0.0, min_support=1,
                                 gp_prior_mean="zero", input_weights=(1.0,) * 23), seed=5)
    learn(a, s.x, s.y)
    learn(b, s.x, s.y)
    np.testing.assert_array_equal(a.assignments(), b.assignments())
    np.testing.assert_array_equal(a.particle_log_weights(), b.particle_log_weights())


def test_infinite_stickiness_keeps_every_point_with_its_predecessor() -> None:
    s = sqrt_multimap(120, seed=2)
    model = Roger(1, 1, RogerParams(beta=20, theta_n=0.01, nu0=3.0, sticky_kappa=math.inf),
                  seed=0)
    learn(model, s.x, s.y)
    assert np.all(model.assignments() == model.assignments()[0])
    assert model.n_experts == 1
    free = Roger(1, 1, RogerParams(beta=20, theta_n=0.01, nu0=3.0), seed=0)
    learn(free, s.x, s.y)
    assert free.n_experts >= 2  # the paper splits this multimap


def test_stickiness_makes_runs_longer() -> None:
    s = subtask_stream(300)

    def repeats(kappa: float) -> float:
        model = Roger(23, 9, RogerParams(beta=20, sticky_kappa=kappa), seed=1)
        learn(model, s.x, s.y)
        a = model.assignments()
        return float(np.mean(a[1:] == a[:-1]))

    sticky = repeats(1e6)
    assert sticky >= repeats(0.0)
    assert sticky > 0.95


# -- d. gate calibration ----------------------------------------------------------------------


def test_min_support_only_changes_prediction() -> None:
    s = subtask_stream(250)
    a = Roger(23, 9, RogerParams(beta=20, lambda0=0.01), seed=3)
    b = Roger(23, 9, RogerParams(beta=20, lambda0=0.01, min_support=30), seed=3)
    learn(a, s.x, s.y)
    learn(b, s.x, s.y)
    np.testing.assert_array_equal(a.assignments(), b.assignments())  # learning unchanged
    sizes = a.expert_sizes()
    assert min(sizes.values()) < 30 <= max(sizes.values())
    for q in s.x[::25]:
        pa = {e.expert_id: e.gate_prob for e in a.predict_multimap(q)}
        pb = {e.expert_id: e.gate_prob for e in b.predict_multimap(q)}
        big = [k for k, n in sizes.items() if n >= 30]
        total = sum(pa[k] for k in big)
        for k, n in sizes.items():
            if n < 30:
                assert pb[k] == 0.0
            elif total > 1e-300:
                assert pb[k] == pytest.approx(pa[k] / total, rel=1e-9, abs=1e-300)
        assert sum(pb.values()) == pytest.approx(1.0)
        assert sizes[b.predict_one(q).expert_id] >= 30
    # no expert with that much support: every expert competes, as without the option
    c = Roger(23, 9, RogerParams(beta=20, lambda0=0.01, min_support=10**6), seed=3)
    learn(c, s.x, s.y)
    for q in s.x[::25]:
        assert [e.gate_prob for e in c.predict_multimap(q)] == [
            e.gate_prob for e in a.predict_multimap(q)]


@pytest.mark.parametrize("kind", [Roger, UnimapGP])
def test_zero_weight_dimensions_are_invisible(kind: type) -> None:
    s = subtask_stream(150)
    noisy = s.x.copy()
    noisy[:, 21] = np.sin(np.arange(150) * 0.7)  # a clock, like the AIBO's tail pan
    noisy[:, 22] = 0.35
    weights = (1.0,) * 21 + (0.0, 0.0)
    a = kind(23, 9, RogerParams(beta=20, input_weights=weights), seed=2)
    b = kind(23, 9, RogerParams(beta=20, input_weights=weights), seed=2)
    learn(a, s.x, s.y)
    learn(b, noisy, s.y)
    np.testing.assert_array_equal(a.assignments(), b.assignments())
    q = s.x[7].copy()
    q2 = q.copy()
    q2[21:] = (5.0, -5.0)
    pa, pb = a.predict_one(q), b.predict_one(q2)
    assert pa.expert_id == pb.expert_id
    np.testing.assert_array_equal(pa.mean, pb.mean)
    np.testing.assert_array_equal(pa.var, pb.var)


def test_input_weight_equals_multiplying_the_data() -> None:
    s = sqrt_multimap(100, seed=5)
    x2 = np.column_stack([s.x[:, 0], np.cos(7 * s.x[:, 0])])
    w = (1.0, 0.25)
    weighted = Roger(2, 1, RogerParams(beta=20, theta_n=0.01, input_weights=w), seed=1)
    manual = Roger(2, 1, RogerParams(beta=20, theta_n=0.01), seed=1)
    learn(weighted, x2, s.y)
    learn(manual, x2 * np.array(w), s.y)
    np.testing.assert_array_equal(weighted.assignments(), manual.assignments())
    np.testing.assert_array_equal(weighted.predict_one(x2[3]).mean,
                                  manual.predict_one(x2[3] * np.array(w)).mean)


def test_dropped_dimensions_relax_the_nu0_check_and_bad_weights_are_refused() -> None:
    Roger(3, 1, RogerParams(nu0=0.5, input_weights=(1.0, 0.0, 0.0)))  # 1 kept: nu0 > 0
    with pytest.raises(ParameterError, match=r"nu0 must be a float > d_x - 1 = 1 .*kept.*2"):
        Roger(3, 1, RogerParams(nu0=0.5, input_weights=(1.0, 1.0, 0.0)))
    with pytest.raises(ParameterError, match="input_weights must be None or a non-empty"):
        RogerParams(input_weights=(0.0, 0.0))
    with pytest.raises(ParameterError, match="input_weights must be None or have length 3"):
        Roger(3, 1, RogerParams(input_weights=(1.0, 1.0)))
    with pytest.raises(ParameterError, match="min_support must be an integer >= 0, got -1"):
        RogerParams(min_support=-1)
    with pytest.raises(ParameterError, match="sticky_kappa must be a float >= 0, got -1.0"):
        RogerParams(sticky_kappa=-1.0)
    with pytest.raises(ParameterError, match="gp_prior_mean must be one of 'zero', 'expert'"):
        RogerParams(gp_prior_mean="data")


# -- f. presets and state -------------------------------------------------------------------


def test_presets() -> None:
    assert RogerParams.preset("paper") == RogerParams()
    default = RogerParams.preset("default")
    for key, value in PRESETS["default"].items():
        assert getattr(default, key) == value
    assert (default.theta_w, default.theta_n, default.gp_prior_mean) == (10.0, 1e-4, "expert")
    assert RogerParams.preset("default", theta_w=3.0).theta_w == 3.0
    with pytest.raises(ParameterError, match="preset must be one of 'paper', 'default'"):
        RogerParams.preset("fast")
    inf = RogerParams(sticky_kappa=math.inf)
    assert RogerParams.from_mapping(json.loads(json.dumps(inf.to_mapping()))) == inf


def test_state_round_trip_with_every_lever_and_schema_1_migration() -> None:
    s = subtask_stream(200)
    params = RogerParams.preset("default", beta=20, theta_w=3.0, sticky_kappa=5.0,
                                input_weights=(1.0,) * 21 + (0.0, 0.5))
    model = Roger(23, 9, params, seed=7)
    learn(model, s.x[:120], s.y[:120])
    loaded = load_model(model.state_dict())
    learn(model, s.x[120:], s.y[120:])
    learn(loaded, s.x[120:], s.y[120:])
    np.testing.assert_array_equal(model.assignments(), loaded.assignments())
    for q in s.x[::40]:
        np.testing.assert_array_equal(model.predict_one(q).mean, loaded.predict_one(q).mean)
    # a schema-1 state (saved before the levers existed) loads as the same paper model
    old = Roger(23, 9, RogerParams(beta=20), seed=7)
    learn(old, s.x[:100], s.y[:100])
    state = with_schema(old.state_dict(), 1, drop=("expert_mean",),
                        drop_params=("gp_prior_mean", "sticky_kappa", "min_support",
                                     "input_weights"))
    assert_same_continuation(old, load_model(state), s.x[100:], s.y[100:])


def assert_same_continuation(model: Roger, restored: Roger, x: np.ndarray,
                             y: np.ndarray) -> None:
    """``restored`` learns ``x, y`` exactly as ``model`` does (partition and weights)."""
    learn(model, x, y)
    learn(restored, x, y)
    np.testing.assert_array_equal(model.assignments(), restored.assignments())
    np.testing.assert_array_equal(model.particle_log_weights(),
                                  restored.particle_log_weights())


def test_a_schema_4_state_with_its_kept_gram_matrix_loads_as_the_same_model() -> None:
    """Schemas 2-4 stored ``K_B`` (``expert_K``); it is ignored on load (recomputed to the same
    floats), and the model continues bit-identically."""
    s = subtask_stream(200)
    params = RogerParams.preset("default", beta=20, theta_w=3.0)
    model = Roger(23, 9, params, seed=3)
    learn(model, s.x[:120], s.y[:120])
    assert "expert_K" not in model.state_dict()
    state = with_schema(model.state_dict(), 4)
    ns = state["expert_n_bv"]
    starts = np.concatenate([[0], np.cumsum(ns)])
    kern = RBFKernel(params.theta_w, 23, params.kernel_dim_scaling)
    state["expert_K"] = np.concatenate(
        [kern.gram(state["expert_B"][a:b], state["expert_B"][a:b]).ravel()
         for a, b in zip(starts[:-1], starts[1:], strict=True)])
    assert_same_continuation(model, load_model(state), s.x[120:], s.y[120:])


# -- K_B recomputed for a re-inversion of Q ------------------------------------------------


def test_the_recomputed_gram_matrix_has_the_floats_of_the_kernel_vectors() -> None:
    """``K_B`` is not kept: a re-inversion recomputes it, and each entry must be the very float
    of the kernel vector computed when that basis vector entered (``expert_terms``, as a
    kept ``K_B`` held), so that recomputing changes no result."""
    from roger_daemon.learner.engine import jit

    rng = np.random.default_rng(5)
    for n, d, width in ((1, 1, 0.5), (7, 3, 0.3), (40, 23, 0.1), (60, 9, 2.0)):
        basis = rng.normal(scale=0.2, size=(n, d))
        basis[n // 2] = basis[0] + 1e-9  # a near-duplicate
        gamma = RBFKernel(width, d).gamma
        gram = jit.gram_matrix(basis, gamma, n)
        zeros = np.zeros(n * (n + 1) // 2)
        for m in range(n):
            k = jit.expert_terms(basis, zeros, np.zeros((n, 2)), basis[m].copy(), gamma, n,
                                 n)[:n]
            np.testing.assert_array_equal(gram[:, m], k)
            np.testing.assert_array_equal(gram[m], k)
        assert np.all(np.diagonal(gram) == 1.0)


@pytest.mark.parametrize("prior_mean", [False, True])
def test_gram_matrix_tracks_the_basis(prior_mean: bool) -> None:
    """Through full updates, fused add-then-delete, KL and geometric deletions and copies, the
    recomputed K_B is the Gram matrix of the basis vectors, and a re-inversion gives K_B^-1."""
    rng = np.random.default_rng(8)
    model = gp(3, 2, width=1.5, capacity=15, threshold=1e-6, prior_mean=prior_mean)
    plain = model.copy()
    plain.fused = False
    for step in range(300):
        x = rng.uniform(-1, 1, 3) if step % 3 else np.full(3, 0.1) + 1e-4 * rng.normal(size=3)
        y = rng.normal(size=2)
        for g in (model, plain):
            g.update(x, y)
            n = g.n
            np.testing.assert_allclose(g.gram, g.kernel.gram(g.B, g.B), rtol=0,
                                       atol=1e-15)
    assert model.q_refreshes > 0 and plain.q_refreshes > 0  # near-duplicates re-invert Q
    model.refresh_inverse_gram()
    n = model.n
    np.testing.assert_allclose(model.Q @ model.gram, np.eye(n), atol=1e-6)
    np.testing.assert_array_equal(model.Q, model.Q.T)


# -- e. kernel width from the data (offline helper) ------------------------------------------


def test_log_evidence_is_the_gaussian_marginal_likelihood() -> None:
    from scipy.stats import multivariate_normal

    from roger_daemon.learner.evidence import log_evidence

    x, y = data(25, 2, 3, seed=9)
    m = y.mean(axis=0)
    cov = RBFKernel(0.8, 2).gram(x, x) + 0.05 * np.eye(25)
    ref = sum(multivariate_normal(np.full(25, m[j]), cov).logpdf(y[:, j]) for j in range(3))
    assert log_evidence(x, y, 0.8, 0.05, prior_mean=m) == pytest.approx(ref, rel=1e-10)


def test_select_width_recovers_the_width_of_a_gp_sample() -> None:
    from roger_daemon.learner.evidence import select_width

    rng = np.random.default_rng(11)
    x = rng.uniform(-2, 2, (150, 2))
    cov = RBFKernel(0.5, 2).gram(x, x) + 1e-3 * np.eye(150)
    y = np.linalg.cholesky(cov) @ rng.normal(size=(150, 2))
    best, scores = select_width(x, y, [0.05, 0.5, 5.0], 1e-3)
    assert best == 0.5 and scores.shape == (3,) and np.argmax(scores) == 1
    best_w, _ = select_width(np.vstack([x, x]), np.vstack([y, y]), [0.05, 0.5, 5.0], 1e-3,
                             window=150, center=True)
    assert best_w == 0.5
    with pytest.raises(ValueError, match="widths must be a non-empty"):
        select_width(x, y, [], 1e-3)
