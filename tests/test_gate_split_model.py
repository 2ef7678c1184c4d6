"""Split gates as a plain one-particle ROGER model (roger_daemon/gate_split_model.py): the
same multimap as :class:`SplitGates`, float for float, so the daemon can serve it."""

from __future__ import annotations

import numpy as np
import pytest

from roger_daemon.gate_split import SplitGates
from roger_daemon.gate_split_model import split_model
from roger_daemon.learner import Roger, RogerParams


def _trained(seed: int) -> tuple[Roger, np.ndarray]:
    """A 10-particle ROGER model on three blobs: two share one policy (one expert spans
    both, so its gate splits), the third has another; the particles disagree and hold
    different versions of their experts."""
    rng = np.random.default_rng(seed)
    blobs = [rng.normal(scale=0.05, size=(n, 3)) + np.array(c)
             for n, c in ((60, (0.0, 0.0, 0.0)), (50, (0.5, 0.0, 0.0)), (40, (0.0, 1.0, 0.0)))]
    x = np.vstack(blobs)[rng.permutation(150)]
    y = np.where(x[:, 1:2] > 0.5, -1.0, 1.0) + 0.3 * np.sin(7 * x[:, 2:3])
    model = Roger(3, 1, RogerParams(particles=10, alpha=1.0), seed=seed)
    for xi, yi in zip(x, y, strict=True):
        model.learn_one(xi, yi)
    return model, x


def _same(split: SplitGates, model: Roger, probe: np.ndarray) -> None:
    p1, t1 = split.predict_table(probe)
    p2, t2 = model.predict_table(probe)
    assert t2.expert_ids == t1.expert_ids and t2.gate_probs == t1.gate_probs
    assert np.array_equal(t2.means, t1.means) and np.array_equal(t2.variances, t1.variances)
    assert list(t2.n_points) == list(t1.n_points)
    assert p2.expert_id == p1.expert_id and np.array_equal(p2.mean, p1.mean)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_split_model_answers_as_the_split_gates_float_for_float(seed: int) -> None:
    model, x = _trained(seed)
    split = SplitGates(model, x, min_points=5)
    served = split_model(split)
    assert len(split.parts) > len({q.expert for q in split.parts})  # a gate was split
    assert served.params.particles == 1 and served.n_experts == len(split.parts)
    assert np.array_equal(served.assignments(), split.assignments())
    assert served.n_learned == model.n_learned
    near = x[::11]
    probes = np.vstack([x[::7], near + np.random.default_rng(seed).normal(0, 0.3, near.shape)])
    reloaded = Roger.from_state_dict(served.state_dict())
    for probe in probes:
        _same(split, served, probe)
        _same(split, reloaded, probe)


def test_a_split_model_can_go_on_learning_as_one_particle() -> None:
    model, x = _trained(3)
    served = split_model(SplitGates(model, x, min_points=5))
    before = served.n_experts
    served.learn_one(np.array([0.0, 0.0, 0.0]), np.array([1.0]))
    assert served.n_learned == model.n_learned + 1
    assert served.n_experts >= before and len(served.assignments()) == served.n_learned
