"""One conformance suite over every learner the project ships (river's ``check_estimator``
spirit): the contract of ``docs/learner-api.md`` checked as properties, model by model."""

from __future__ import annotations

import io
from typing import Any

import numpy as np
import pytest

from roger_daemon.learner import RogerParams, load_model
from roger_daemon.learner.protocol import MODELS, Learner

D_X, D_Y = 3, 2
PARAMS = RogerParams(particles=4, beta=20)


def _stream(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Two interleaved branches over the same inputs: a small multimap."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(-1.0, 1.0, (n, D_X))
    sign = np.where(np.arange(n) % 40 < 20, 1.0, -1.0)[:, None]
    y = np.hstack([np.sin(2 * x[:, :1]), x[:, 1:2] ** 2]) * sign
    return x, y


def _fresh(cls: Any, seed: int = 0) -> Any:
    return cls(D_X, D_Y, params=PARAMS, seed=seed)


def _trained(cls: Any, n: int = 60, seed: int = 0) -> Any:
    model = _fresh(cls, seed)
    for x, y in zip(*_stream(n), strict=True):
        model.learn_one(x, y)
    return model


def _same_state(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> bool:
    """Bit-for-bit equal named arrays (NaN padding counts as equal to NaN padding)."""
    return a.keys() == b.keys() and all(
        np.array_equal(a[k], b[k], equal_nan=a[k].dtype.kind in "fc") for k in a)


models = pytest.mark.parametrize("cls", MODELS, ids=[c.__name__ for c in MODELS])


@models
def test_is_a_learner_and_the_constructor_only_stores(cls: Any) -> None:
    model = _fresh(cls)
    assert isinstance(model, Learner)
    assert (model.d_x, model.d_y, model.n_learned) == (D_X, D_Y, 0)
    assert model.assignments().size == 0 and model.expert_sizes() == {}
    for bad in (0, -1, 2.5, True):
        with pytest.raises(ValueError):
            cls(bad, D_Y, params=PARAMS)


@models
def test_before_learning_it_predicts_the_prior(cls: Any) -> None:
    p = _fresh(cls).predict_one(np.zeros(D_X))
    assert p.expert_id == -1 and p.mean.shape == p.var.shape == (D_Y,)
    assert np.all(np.isfinite(p.mean)) and np.all(p.var > 0)


@models
def test_learn_one_counts_and_bad_input_changes_nothing(cls: Any) -> None:
    model = _trained(cls, 30)
    before = model.state_dict()
    for x, y in [(np.zeros(D_X + 1), np.zeros(D_Y)), (np.zeros(D_X), np.zeros(D_Y + 1)),
                 (np.full(D_X, np.nan), np.zeros(D_Y)), (np.zeros(D_X), np.full(D_Y, np.inf))]:
        with pytest.raises(ValueError):
            model.learn_one(x, y)
    assert model.n_learned == 30 and _same_state(before, model.state_dict())


@models
def test_predictions_are_well_formed_and_change_nothing(cls: Any) -> None:
    model = _trained(cls)
    before = model.state_dict()
    for q in _stream(10, seed=5)[0]:
        p = model.predict_one(q)
        assert p.mean.shape == p.var.shape == (D_Y,) and np.all(p.var > 0)
        assert 0.0 <= p.gate_prob <= 1.0
        mm = model.predict_multimap(q)
        ids = [e.expert_id for e in mm]
        assert len(set(ids)) == len(ids) == model.n_experts
        assert p.expert_id in ids or p.expert_id == -1
        assert all(0.0 <= e.gate_prob <= 1.0 and np.all(e.var > 0) for e in mm)
        assert sum(e.gate_prob for e in mm) <= 1.0 + 1e-9
        assert {e.expert_id: e.n_points for e in mm} == model.expert_sizes()
    assert _same_state(before, model.state_dict())


@models
def test_assignments_agree_with_the_experts(cls: Any) -> None:
    model = _trained(cls)
    a = model.assignments()
    assert a.dtype == np.int64 and a.size == model.n_learned
    sizes = model.expert_sizes()
    assert sum(sizes.values()) == model.n_learned and len(sizes) == model.n_experts
    assert {int(e): int(np.sum(a == e)) for e in np.unique(a)} == sizes


@models
def test_settled_assignments_never_change(cls: Any) -> None:
    model = _fresh(cls, 0)
    xs, ys = _stream(120)
    seen: list[tuple[np.ndarray, np.ndarray]] = []
    rng = np.random.default_rng(0)
    for x, y in zip(xs, ys, strict=True):
        model.learn_one(x, y)
        a = model.assignments()
        unsettled = model.unsettled_points()
        assert unsettled.dtype == np.int64 and np.all(np.diff(unsettled) > 0)
        assert unsettled.size == 0 or 0 <= unsettled[0] <= unsettled[-1] < model.n_learned
        some = rng.integers(0, model.n_learned, 7)
        np.testing.assert_array_equal(model.assignments_at(some), a[some])
        settled = np.setdiff1d(np.arange(model.n_learned), unsettled)
        seen.append((settled, a[settled]))
    final = model.assignments()
    for points, ids in seen:  # what was settled then is what the model says now
        np.testing.assert_array_equal(final[points], ids)


@models
def test_same_seed_same_model(cls: Any) -> None:
    assert _same_state(_trained(cls).state_dict(), _trained(cls).state_dict())


@models
def test_state_dict_round_trips_without_pickle_and_continues_exactly(cls: Any) -> None:
    model = _trained(cls, 40)
    buf = io.BytesIO()
    np.savez(buf, **model.state_dict())
    buf.seek(0)
    with np.load(buf, allow_pickle=False) as f:
        restored = load_model(f)
    assert type(restored) is cls and restored.n_learned == 40
    xs, ys = _stream(70)
    for x, y in zip(xs[40:], ys[40:], strict=True):  # both continue on the same pairs
        model.learn_one(x, y)
        restored.learn_one(x, y)
    assert _same_state(model.state_dict(), restored.state_dict())
    q = xs[0]
    assert np.array_equal(model.predict_one(q).mean, restored.predict_one(q).mean)


#: the settings the one-pass answers are checked with: argmax, and draws with the empty expert
ANSWER_PARAMS = (PARAMS, PARAMS.replace(expert_choice="sample", predict_empty_expert=True))


def _twins(cls: Any, params: RogerParams) -> tuple[Any, Any]:
    """Two identically seeded models: one asked in one pass, the other call by call."""
    return cls(D_X, D_Y, params=params, seed=3), cls(D_X, D_Y, params=params, seed=3)


def _learn_both(*models: Any) -> None:
    for model in models:
        for x, y in zip(*_stream(50), strict=True):
            model.learn_one(x, y)


@models
def test_predict_with_multimap_is_both_calls_in_one(cls: Any) -> None:
    # float for float and draw for draw: two identically seeded models, one asked twice
    for params in ANSWER_PARAMS:
        a, b = _twins(cls, params)
        _learn_both(a, b)
        for q in _stream(8, seed=6)[0]:
            pred, mm = a.predict_with_multimap(q)
            assert _same_prediction(pred, b.predict_one(q))
            assert [_fields(e) for e in mm] == [_fields(e) for e in b.predict_multimap(q)]
    empty = _fresh(cls)
    pred, mm = empty.predict_with_multimap(np.zeros(D_X))
    assert pred.expert_id == -1 and mm == []


@models
def test_predict_table_is_predict_one_and_predict_multimap_as_arrays(cls: Any) -> None:
    # float for float and draw for draw, with and without the empty expert, before learning too
    for params in ANSWER_PARAMS:
        a, b = _twins(cls, params)
        queries = _stream(8, seed=6)[0]
        for q in queries[:2]:  # before learning: the prior, and its row if it takes part
            _same_table(a.predict_table(q), (b.predict_one(q), b.predict_multimap(q)))
        _learn_both(a, b)
        for q in queries:
            _same_table(a.predict_table(q), (b.predict_one(q), b.predict_multimap(q)))
    with pytest.raises(ValueError):
        _fresh(cls).predict_table(np.zeros(D_X + 1))


def _same_table(got: Any, want: Any) -> None:
    (pred, table), (want_pred, want_mm) = got, want
    assert _same_prediction(pred, want_pred)
    assert table.means.shape == table.variances.shape == (len(want_mm), D_Y)
    assert [_fields(e) for e in table.experts()] == [_fields(e) for e in want_mm]
    assert [type(v) for v in table.expert_ids + table.n_points] == [int] * 2 * len(want_mm)
    assert all(type(v) is float for v in table.gate_probs)


def _fields(e: Any) -> tuple[Any, ...]:
    return (e.expert_id, e.gate_prob, e.mean.tolist(), e.var.tolist(), e.n_points)


def _same_prediction(a: Any, b: Any) -> bool:
    return (a.expert_id, a.gate_prob, a.mean.tolist(), a.var.tolist()) == (
        b.expert_id, b.gate_prob, b.mean.tolist(), b.var.tolist())


def test_the_registry_builds_and_reloads_every_kind_it_names() -> None:
    from roger_daemon.config.models import MODELS as DAEMON_MODELS
    from roger_daemon.config.models import build_model
    from roger_daemon.learner.registry import MODELS as REGISTRY
    from roger_daemon.learner.registry import load_model

    assert {k: DAEMON_MODELS[k] for k in REGISTRY} == REGISTRY  # the daemon's extends it
    for kind, cls in REGISTRY.items():
        model = build_model(kind, 2, 1, {"beta": 5}, seed=1)
        assert type(model) is cls and model.kind == kind and model.params.beta == 5
        model.learn_one(np.array([0.1, 0.2]), np.array([0.3]))
        assert type(load_model(model.state_dict())) is cls
    with pytest.raises(ValueError, match="unknown model kind 'nope' \\(one of roger, unimap, "):
        build_model("nope", 2, 1)
