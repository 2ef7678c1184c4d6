"""fit_partition: ROGER with a given partition, against the exact oracle of one GP per group."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from roger_daemon.learner import Roger, RogerParams, UnimapGP
from roger_daemon.learner.partition import fit_partition

PARAMS = RogerParams(nu0=4.0, theta_w=1.0, particles=7)


def _data(n: int = 60) -> tuple[np.ndarray, np.ndarray, list[str]]:
    rng = np.random.default_rng(3)
    x = rng.uniform(-1, 1, (n, 2))
    groups = ["a" if v > 0 else "b" for v in rng.standard_normal(n)]
    y = np.where(np.array(groups)[:, None] == "a", 1.0, -1.0) + 0.2 * x
    return x, y, groups


def test_each_expert_is_the_gp_of_its_groups_points() -> None:
    x, y, groups = _data()
    model = fit_partition(x, y, groups, params=PARAMS, seed=0)
    assert isinstance(model, Roger) and model.n_particles == 1 and model.params.particles == 1
    first = list(dict.fromkeys(groups))
    assert model.assignments().tolist() == [first.index(g) for g in groups]
    assert model.expert_sizes() == {i: groups.count(g) for i, g in enumerate(first)}
    q = np.array([[0.3, -0.2], [-0.9, 0.8]])
    for i, g in enumerate(first):
        gp = UnimapGP(d_x=2, d_y=2, params=PARAMS, seed=0)
        for xi, yi, gi in zip(x, y, groups, strict=True):
            if gi == g:
                gp.learn_one(xi, yi)
        for qi in q:
            mine = {e.expert_id: e for e in model.predict_multimap(qi)}[i]
            oracle = gp.predict_one(qi)
            np.testing.assert_allclose(mine.mean, oracle.mean, rtol=1e-9, atol=1e-12)
            np.testing.assert_allclose(mine.var, oracle.var, rtol=1e-9, atol=1e-12)


def test_the_model_round_trips_through_its_state_dict() -> None:
    x, y, groups = _data(30)
    model = fit_partition(x, y, groups, params=PARAMS, seed=0)
    again = Roger.from_state_dict(model.state_dict())
    assert again.assignments().tolist() == model.assignments().tolist()
    q = np.array([0.1, 0.2])
    assert np.array_equal(again.predict_one(q).mean, model.predict_one(q).mean)


def test_bad_shapes_are_refused() -> None:
    x, y, groups = _data(10)
    with pytest.raises(ValueError, match="n groups expected"):
        fit_partition(x, y, groups[:-1], params=PARAMS)
    with pytest.raises(ValueError, match="x \\(n, d_x\\)"):
        fit_partition(x[:, 0], y, groups, params=PARAMS)


def test_learn_assigned_needs_one_particle_and_an_expert_it_has() -> None:
    x, y, groups = _data(6)
    model = fit_partition(x, y, groups, params=PARAMS, seed=0)
    n, sizes = model.n_learned, model.expert_sizes()
    with pytest.raises(ValueError, match="the particle has no expert 99"):
        model.learn_assigned(x[0], y[0], 99)
    assert (model.n_learned, model.expert_sizes()) == (n, sizes)  # unchanged
    assert model.learn_assigned(x[0], y[0], 0) == 0 and model.expert_sizes()[0] == sizes[0] + 1
    two = Roger(x.shape[1], y.shape[1], replace(PARAMS, particles=2), seed=0)
    for xi, yi in zip(x, y, strict=True):
        two.learn_one(xi, yi)
    assert two.n_particles == 2
    with pytest.raises(ValueError, match="needs a model of one particle, not 2"):
        two.learn_assigned(x[0], y[0], None)
