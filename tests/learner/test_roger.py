"""ROGER model: multimap behaviour, determinism, state round trips, validation, bounds."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from roger_daemon.learner import (
    ExpertPrediction,
    ParameterError,
    Prediction,
    Roger,
    RogerParams,
    UnimapGP,
    load_model,
)
from roger_daemon.learner.roger_step import putatives
from roger_daemon.learner.synthetic import sqrt_multimap, subtask_stream

GRID = np.linspace(0.25, 1.0, 16)


def learn(model: Roger | UnimapGP, x: np.ndarray, y: np.ndarray) -> None:
    for xi, yi in zip(x, y, strict=True):
        model.learn_one(xi, yi)


def assert_same_state(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> None:
    assert sorted(a) == sorted(b)
    for key in a:
        if key == "meta":
            assert json.loads(str(a[key])) == json.loads(str(b[key]))
        else:
            assert a[key].dtype == b[key].dtype, key
            np.testing.assert_array_equal(a[key], b[key], err_msg=key)


def small_params(**kw: object) -> RogerParams:
    return RogerParams(beta=25, **kw)  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def stream23() -> tuple[np.ndarray, np.ndarray]:
    s = subtask_stream(300)
    return s.x, s.y


# -- behaviour -----------------------------------------------------------------------------


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_sqrt_multimap_roger_covers_both_branches_unimap_averages(seed: int) -> None:
    """y = +sqrt(x) / -sqrt(x) interleaved; theta_n matched to the toy's small noise."""
    s = sqrt_multimap(400, seed=seed)
    params = RogerParams(theta_n=0.01)
    model = Roger(1, 1, params, seed=seed)
    base = UnimapGP(1, 1, params)
    learn(model, s.x, s.y)
    learn(base, s.x, s.y)
    assert model.n_experts >= 2
    err_plus, err_minus, uni_mean, uni_err = [], [], [], []
    for xq in GRID:
        branches = model.predict_multimap([xq])
        means = np.array([b.mean[0] for b in branches])
        err_plus.append(np.min(np.abs(means - math.sqrt(xq))))
        err_minus.append(np.min(np.abs(means + math.sqrt(xq))))
        u = float(base.predict_one([xq]).mean[0])
        uni_mean.append(abs(u))
        uni_err.append(min(abs(u - math.sqrt(xq)), abs(u + math.sqrt(xq))))
    assert np.mean(err_plus) < 0.05 and np.mean(err_minus) < 0.05
    assert np.mean(uni_mean) < 0.2  # near the average of the branches (0) ...
    assert np.mean(uni_err) > 0.4  # ... hence far from both
    # Branch purity of the segmentation is *not* an oracle here: an RBF expert can follow +sqrt
    # on one x-interval and -sqrt on another, so "crossing" decompositions are equally valid.
    # What must hold is that every learned point is explained by its own expert.
    assign = model.assignments()
    for eid in np.unique(assign):
        branch = next(b for b in model.predict_multimap([0.5]) if b.expert_id == eid)
        assert branch.n_points == int(np.sum(assign == eid))


def test_multimap_fields_and_gate_probabilities(stream23: tuple[np.ndarray, np.ndarray]) -> None:
    x, y = stream23
    model = Roger(23, 9, small_params(), seed=3)
    learn(model, x, y)
    branches = model.predict_multimap(x[5])
    assert len(branches) == model.n_experts
    assert all(isinstance(b, ExpertPrediction) for b in branches)
    assert math.isclose(sum(b.gate_prob for b in branches), 1.0, rel_tol=1e-12)
    sizes = model.expert_sizes()
    assert {b.expert_id for b in branches} == set(sizes)
    for b in branches:
        assert b.mean.shape == (9,) and b.var.shape == (9,) and np.all(b.var > 0)
        assert b.n_points == sizes[b.expert_id]
    pred = model.predict_one(x[5])
    assert isinstance(pred, Prediction)
    best = max(branches, key=lambda b: b.gate_prob)
    assert pred.expert_id == best.expert_id  # argmax by default
    np.testing.assert_array_equal(pred.mean, best.mean)
    assert pred.gate_prob == best.gate_prob


def test_multimap_branches_are_each_experts_own_prediction(
        stream23: tuple[np.ndarray, np.ndarray]) -> None:
    """The multimap scales every branch back to output units in one pass: the same floats as
    each expert's prediction on its own (with a non-trivial output scaling)."""
    from roger_daemon.learner import roger_predict

    x, y = stream23
    model = Roger(23, 9, small_params(y_offset=list(np.linspace(-1.0, 1.0, 9)),
                                      y_scale=list(np.linspace(0.5, 3.0, 9))), seed=3)
    learn(model, x, y)
    for q in (x[5], x[40], x[-1] + 0.3):
        branches = model.predict_multimap(q)
        xs = model.terms.scaling.x_in(np.asarray(q, dtype=np.float64))
        slots = model.particle_slots(model.store.map_particle()).tolist()
        assert len(branches) == len(slots) > 1
        for b, slot in zip(branches, slots, strict=True):
            own = roger_predict._expert(model.store, model.terms, slot, xs, b.gate_prob)
            assert (b.expert_id, b.n_points) == (own.expert_id, own.n_points)
            np.testing.assert_array_equal(b.mean, own.mean)
            np.testing.assert_array_equal(b.var, own.var)


def test_assignments_agree_with_expert_sizes(stream23: tuple[np.ndarray, np.ndarray]) -> None:
    x, y = stream23
    model = Roger(23, 9, small_params(), seed=4)
    learn(model, x, y)
    assign = model.assignments()
    assert assign.dtype == np.int64 and assign.shape == (len(x),)
    ids, counts = np.unique(assign, return_counts=True)
    assert dict(zip(ids.tolist(), counts.tolist(), strict=True)) == model.expert_sizes()
    assert model.n_learned == len(x)
    assert sum(model.expert_sizes().values()) == len(x)


def test_expert_ids_are_stable_and_unique_over_time() -> None:
    s = sqrt_multimap(200, seed=5)
    model = Roger(1, 1, RogerParams(theta_n=0.01), seed=5)
    for step, (xi, yi) in enumerate(zip(s.x, s.y, strict=True)):
        model.learn_one(xi, yi)
        if step % 20 == 19:
            # stable between calls, and the same ids everywhere
            assert model.expert_sizes() == model.expert_sizes()
            ids = [b.expert_id for b in model.predict_multimap([0.5])]
            assert len(set(ids)) == len(ids) == model.n_experts
            assert set(ids) == set(model.expert_sizes()) == set(model.assignments().tolist())
    # ids are handed out in order of creation: first use in the segmentation is increasing
    assign = model.assignments()
    first = {int(e): int(np.argmax(assign == e)) for e in np.unique(assign)}
    assert sorted(first, key=first.__getitem__) == sorted(first)


def test_prediction_before_learning_is_the_prior() -> None:
    params = RogerParams(y_offset=(1.0, -2.0), y_scale=(2.0, 1.0))
    model = Roger(3, 2, params, seed=0)
    pred = model.predict_one(np.zeros(3))
    assert pred.expert_id == -1 and pred.gate_prob == 1.0
    np.testing.assert_allclose(pred.mean, [1.0, -2.0])
    np.testing.assert_allclose(pred.var, [4.0 * 1.1, 1.1])  # (k* + s0^2) * scale^2
    assert model.predict_multimap(np.zeros(3)) == []
    assert model.n_experts == 0 and model.n_learned == 0 and model.assignments().size == 0
    base = UnimapGP(3, 2, params)
    assert base.predict_one(np.zeros(3)).expert_id == -1
    assert base.predict_multimap(np.zeros(3)) == [] and base.n_experts == 0


def test_empty_expert_takes_part_when_asked() -> None:
    s = sqrt_multimap(60, seed=1)
    model = Roger(1, 1, RogerParams(predict_empty_expert=True), seed=1)
    learn(model, s.x, s.y)
    branches = model.predict_multimap([5.0])  # far away: the prior is the likeliest gate
    assert branches[-1].expert_id == -1 and branches[-1].n_points == 0
    assert math.isclose(sum(b.gate_prob for b in branches), 1.0, rel_tol=1e-12)
    assert len(branches) == model.n_experts + 1


def test_sampled_expert_choice_follows_gate_probabilities() -> None:
    s = sqrt_multimap(300, seed=2)
    model = Roger(1, 1, RogerParams(theta_n=0.01, expert_choice="sample"), seed=2)
    learn(model, s.x, s.y)
    probs = {b.expert_id: b.gate_prob for b in model.predict_multimap([0.6])}
    rng = np.random.default_rng(0)
    draws = [model.predict_one([0.6], rng=rng).expert_id for _ in range(4000)]
    for eid, p in probs.items():
        freq = draws.count(eid) / len(draws)
        assert abs(freq - p) < 5 * math.sqrt(p * (1 - p) / len(draws)) + 1e-3


def test_unimap_baseline_api() -> None:
    s = sqrt_multimap(50, seed=0)
    base = UnimapGP(1, 1, RogerParams(beta=10), seed=0)
    learn(base, s.x, s.y)
    assert base.n_experts == 1 and base.n_learned == 50
    assert base.expert_sizes() == {0: 50}
    np.testing.assert_array_equal(base.assignments(), np.zeros(50, dtype=np.int64))
    (branch,) = base.predict_multimap([0.5])
    assert branch.gate_prob == 1.0 and branch.expert_id == 0
    assert base.basis_sizes()[0] <= 10


def test_affine_scaling_is_equivalent_to_scaling_the_data() -> None:
    s = sqrt_multimap(150, seed=3)
    # dyadic data: scaling by 4 and 0.5 and shifting by 10 and -3 are then exact in floating
    # point, so both models see bit-identical numbers (ill-conditioned Q would amplify round-off)
    xs, ys = np.round(s.x * 1024) / 1024, np.round(s.y * 1024) / 1024
    plain = Roger(1, 1, RogerParams(theta_n=0.01), seed=9)
    scaled = Roger(1, 1, RogerParams(theta_n=0.01, x_offset=(10.0,), x_scale=(4.0,),
                                     y_offset=(-3.0,), y_scale=(0.5,)), seed=9)
    for xi, yi in zip(xs, ys, strict=True):
        plain.learn_one(xi, yi)
        scaled.learn_one(xi * 4.0 + 10.0, yi * 0.5 - 3.0)
    assert plain.expert_sizes() == scaled.expert_sizes()
    a = plain.predict_one([0.5])
    b = scaled.predict_one([0.5 * 4.0 + 10.0])
    np.testing.assert_allclose(b.mean, a.mean * 0.5 - 3.0, rtol=1e-12)
    np.testing.assert_allclose(b.var, a.var * 0.25, rtol=1e-12)


# -- determinism and state -----------------------------------------------------------------


def test_same_seed_same_model_and_predictions(stream23: tuple[np.ndarray, np.ndarray]) -> None:
    x, y = stream23
    params = small_params(expert_choice="sample")
    a, b = Roger(23, 9, params, seed=11), Roger(23, 9, params, seed=11)
    learn(a, x, y)
    learn(b, x, y)
    assert_same_state(a.state_dict(), b.state_dict())
    for q in x[:20]:
        pa, pb = a.predict_one(q), b.predict_one(q)
        assert pa.expert_id == pb.expert_id
        np.testing.assert_array_equal(pa.mean, pb.mean)
    gen_a = Roger(23, 9, params, seed=np.random.default_rng(5))
    gen_b = Roger(23, 9, params, seed=np.random.default_rng(5))
    learn(gen_a, x[:80], y[:80])
    learn(gen_b, x[:80], y[:80])
    assert_same_state(gen_a.state_dict(), gen_b.state_dict())


def test_predictions_never_perturb_learning(stream23: tuple[np.ndarray, np.ndarray]) -> None:
    x, y = stream23
    params = small_params(expert_choice="sample")
    quiet, chatty = Roger(23, 9, params, seed=12), Roger(23, 9, params, seed=12)
    for xi, yi in zip(x, y, strict=True):
        quiet.learn_one(xi, yi)
        chatty.learn_one(xi, yi)
        chatty.predict_one(xi)
        chatty.predict_multimap(xi)
    sq, sc = quiet.state_dict(), chatty.state_dict()
    meta_q, meta_c = json.loads(str(sq.pop("meta"))), json.loads(str(sc.pop("meta")))
    assert meta_q.pop("rng_predict") != meta_c.pop("rng_predict")
    assert meta_q == meta_c
    for key in sq:
        np.testing.assert_array_equal(sq[key], sc[key])


@pytest.mark.parametrize("kind", [Roger, UnimapGP])
def test_state_dict_round_trip_through_npz(kind: type, tmp_path: Path,
                                           stream23: tuple[np.ndarray, np.ndarray]) -> None:
    x, y = stream23
    params = small_params(expert_choice="sample")
    model = kind(23, 9, params, seed=13)
    learn(model, x[:200], y[:200])
    state = model.state_dict()
    assert all(isinstance(v, np.ndarray) and v.dtype != object for v in state.values())
    assert state["meta"].shape == () and state["meta"].dtype.kind == "U"
    path = tmp_path / "model.npz"
    np.savez(path, **state)
    with np.load(path, allow_pickle=False) as npz:
        loaded = load_model(npz)
    assert type(loaded) is kind
    assert_same_state(state, loaded.state_dict())
    # identical predictions and identical continued learning
    for q in x[200:210]:
        pa, pb = model.predict_one(q), loaded.predict_one(q)
        assert pa.expert_id == pb.expert_id
        np.testing.assert_array_equal(pa.mean, pb.mean)
        np.testing.assert_array_equal(pa.var, pb.var)
    learn(model, x[200:], y[200:])
    learn(loaded, x[200:], y[200:])
    assert_same_state(model.state_dict(), loaded.state_dict())
    np.testing.assert_array_equal(model.assignments(), loaded.assignments())


def test_load_model_rejects_foreign_state() -> None:
    state = Roger(2, 1, seed=0).state_dict()
    meta = json.loads(str(state["meta"]))
    meta["schema"] = 999
    with pytest.raises(ValueError, match="schema"):
        load_model({**state, "meta": np.array(json.dumps(meta))})
    meta["schema"], meta["kind"] = 1, "teapot"
    with pytest.raises(ValueError, match="teapot"):
        load_model({**state, "meta": np.array(json.dumps(meta))})
    with pytest.raises(ValueError, match="meta"):
        load_model({k: v for k, v in state.items() if k != "meta"})


# -- bounds ----------------------------------------------------------------------------------


def check_bounded(model: Roger) -> None:
    p = model.params
    assert model.n_particles == p.particles
    gps = model.distinct_experts()
    assert gps and all(g.n <= p.beta for g in gps)
    assert all(g.alloc <= p.beta for g in gps)  # buffers too
    assert model.n_unique_experts == len(gps)
    # every particle's experts are in the pool; the pool holds nothing else
    assert model.n_unique_experts <= model.store.slots.size


def test_memory_bounded_fast_variant() -> None:
    s = subtask_stream(2500, d_x=5, d_y=2)
    model = Roger(5, 2, RogerParams(beta=30, nu0=6.0), seed=1)
    learn(model, s.x, s.y)
    check_bounded(model)
    assert model.n_learned == 2500


@pytest.mark.slow
def test_memory_bounded_after_20000_updates_paper_params() -> None:
    s = subtask_stream(20000)
    model = Roger(23, 9, seed=0)
    for i, (xi, yi) in enumerate(zip(s.x, s.y, strict=True)):
        model.learn_one(xi, yi)
        if i % 5000 == 4999:
            check_bounded(model)
    check_bounded(model)
    assert model.assignments().size == 20000


# -- validation ----------------------------------------------------------------------------


@pytest.mark.parametrize("bad", [
    np.zeros(4), np.zeros((1, 3)), [0.0, np.nan, 0.0], [np.inf, 0.0, 0.0], "abc", [1, 2, "x"],
])
def test_bad_input_raises_and_leaves_model_unchanged(bad: object) -> None:
    s = sqrt_multimap(30, seed=0)
    model = Roger(3, 2, seed=0)
    for xi, yi in zip(s.x, s.y, strict=True):
        model.learn_one(np.repeat(xi, 3), np.repeat(yi, 2))
    before = model.state_dict()
    with pytest.raises(ValueError):
        model.learn_one(bad, np.zeros(2))  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        model.learn_one(np.zeros(3), bad)  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        model.predict_one(bad)  # type: ignore[arg-type]
    assert_same_state(before, model.state_dict())
    base = UnimapGP(3, 2)
    with pytest.raises(ValueError):
        base.learn_one(bad, np.zeros(2))  # type: ignore[arg-type]
    assert base.n_learned == 0


@pytest.mark.parametrize(("field", "value", "expected"), [
    ("alpha", -1.0, "alpha must be a float > 0, got -1.0"),
    ("alpha", float("nan"), "alpha must be a float > 0"),
    ("kappa0", 0.0, "kappa0 must be a float > 0, got 0.0"),
    ("beta", 0, "beta must be an integer >= 1, got 0"),
    ("particles", 2.5, "particles must be an integer >= 1, got 2.5"),
    ("theta_w", "wide", "theta_w must be a float > 0, got 'wide'"),
    ("novelty_threshold", -1e-3, "novelty_threshold must be a float >= 0, got -0.001"),
    ("kernel_dim_scaling", "cubic", "kernel_dim_scaling must be one of 'textbook', 'grollman'"),
    ("expert_choice", "vote", "expert_choice must be one of 'argmax', 'sample', got 'vote'"),
    ("predict_empty_expert", 1, "predict_empty_expert must be a bool, got 1"),
    ("y_scale", (1.0, 0.0), "y_scale must be None or a non-empty sequence of finite floats > 0"),
    ("prune_log_margin", -1.0, "prune_log_margin must be a float > 0"),
])
def test_bad_parameter_names_range_and_value(field: str, value: object, expected: str) -> None:
    with pytest.raises(ParameterError) as info:
        RogerParams(**{field: value})  # type: ignore[arg-type]
    assert expected in str(info.value)
    assert isinstance(info.value, ValueError)


def test_dimension_dependent_parameter_checks() -> None:
    with pytest.raises(ParameterError, match=r"nu0 must be a float > d_x - 1 = 22.*got 20.0"):
        Roger(23, 9, RogerParams(nu0=20.0))
    with pytest.raises(ParameterError, match="x_scale must be None or have length 2, got length 3"):
        Roger(2, 1, RogerParams(x_scale=(1.0, 1.0, 1.0)))
    with pytest.raises(ValueError, match="d_x must be an integer >= 1"):
        Roger(0, 1)


def test_params_mapping_round_trip_and_unknown_key() -> None:
    params = RogerParams(alpha=2.0, beta=50, x_offset=(1.0, 2.0), kernel_dim_scaling="grollman")
    mapping = params.to_mapping()
    assert json.loads(json.dumps(mapping)) == mapping
    assert RogerParams.from_mapping(mapping) == params
    assert RogerParams.from_mapping({}) == RogerParams()
    assert RogerParams().alpha == 0.5 and RogerParams().beta == 300
    # nu0: the paper's 24 for its 23-D input, d_x + 1 for any other (issue 56)
    assert RogerParams().nu0 is None and Roger(23, 9).params.nu0 == 24.0
    with pytest.raises(ParameterError, match="unknown parameter.*'P'"):
        RogerParams.from_mapping({"P": 10})
    with pytest.raises(AttributeError):
        params.alpha = 1.0  # type: ignore[misc]


def test_opt_in_pruning_only_drops_negligible_putatives(
        stream23: tuple[np.ndarray, np.ndarray]) -> None:
    x, y = stream23
    exact = Roger(23, 9, small_params(), seed=21)
    learn(exact, x[:250], y[:250])
    state = exact.state_dict()
    meta = json.loads(str(state["meta"]))
    meta["params"]["prune_log_margin"] = 30.0
    pruned = Roger.from_state_dict({**state, "meta": np.array(json.dumps(meta))})
    dropped = 0
    for xi, yi in zip(x[250:], y[250:], strict=True):
        lw_exact = putatives(exact.store, exact.terms, exact.history, xi, yi).log_weights
        lw_pruned = putatives(pruned.store, pruned.terms, pruned.history, xi, yi).log_weights
        kept = np.isfinite(lw_pruned)
        np.testing.assert_array_equal(lw_pruned[kept], lw_exact[kept])
        assert np.all(lw_exact[~kept] < lw_exact.max() - 30.0)
        dropped += int((~kept).sum())
    assert dropped > 0
    # the bound behind it: no expert's log-likelihood exceeds -(d_y/2) log(2 pi theta_n)
    for gp in exact.distinct_experts():
        for xi, yi in zip(x[:20], y[:20], strict=True):
            assert gp.log_likelihood(xi, yi) <= exact.terms.gp_bound


def test_nu0_follows_d_x_unless_set() -> None:
    """`Roger(d_x=30)` used to fail (nu0 = 24 <= 29); nu0 is d_x + 1 unless given."""
    model = Roger(30, 2, RogerParams.preset("default"), seed=0)
    assert model.params.nu0 == 31.0
    rng = np.random.default_rng(0)
    for _ in range(30):
        model.learn_one(rng.normal(size=30), rng.normal(size=2))
    pred = model.predict_one(rng.normal(size=30))
    assert model.n_learned == 30 and np.all(np.isfinite(pred.mean))
    assert Roger(30, 2, RogerParams(nu0=40.0)).params.nu0 == 40.0
    assert Roger(23, 9, RogerParams()).params == RogerParams(nu0=24.0)  # the AIBO's, unchanged
    with pytest.raises(ParameterError, match="nu0 must be a float > d_x - 1 = 29"):
        Roger(30, 2, RogerParams(nu0=24.0))
