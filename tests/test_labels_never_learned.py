"""The demonstrator's labels never enter learning: shuffled labels, the same models.

The experiment's training (``pipeline.train_models``: ROGER per learner seed and the unimap
GP) and its learned transitions (``pipeline.fit_transitions``) take a stream whose labels are
carried beside the pairs; permuting the labels changes neither the models' state dicts nor
the FSM's, with the experts' own gates or with split gates (``--gates split``, whose parts
the FSM learns over). (The downsampling picks points by label, as in the paper; it runs
before this.)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pytest

from roger_daemon.daemon.checkpoint import array_digest
from roger_daemon.learner import RogerParams
from simulator.experiment.pipeline import fit_transitions, train_models
from simulator.experiment.training import Demonstrations


@dataclass
class _Plan:
    learner_seeds: int = 2
    seeds: dict[str, int] = field(default_factory=lambda: {"learner": 5})
    controllers: tuple[str, ...] = ("roger", "autonomous")
    gates: str = "niw"


def _stream(labels: list[str]) -> Demonstrations:
    rng = np.random.default_rng(1)
    n = len(labels)
    x = rng.normal(0.0, 0.3, size=(n, 23))
    x[:, 2] = np.where(np.arange(n) % 7 < 3, 0.2, -1.0)  # the ball seen or not
    y = np.zeros((n, 9))
    y[:, 2] = np.where(np.arange(n) % 2 == 0, 1.5, -1.5) * (x[:, 2] < 0)
    y[:, 0] = 0.2 * (x[:, 2] > 0)
    tick = np.arange(n) % 40
    return Demonstrations(x, y, labels, np.zeros(n, dtype=np.int64), tick, 0)


def _digests(labels: list[str], gates: str = "niw") -> tuple[list[str], str, list[str]]:
    stream = _stream(labels)
    params = RogerParams.preset("default").replace(particles=5, beta=20)
    plan: Any = _Plan(gates=gates)
    models, unimap, _ = train_models(stream, params, plan)
    fsms = fit_transitions(stream, models, plan, stream)
    return ([array_digest(m.state_dict()) for _, m in models],
            array_digest(unimap.state_dict()), [array_digest(f.state_dict()) for f in fsms])


@pytest.mark.parametrize("gates", ["niw", "split"])
def test_shuffled_labels_give_the_same_models_and_transitions(gates: str) -> None:
    n = 160
    labels = [("seek", "approach", "kick", "aim")[(i // 10) % 4] for i in range(n)]
    shuffled = list(np.random.default_rng(2).permutation(labels))
    assert shuffled != labels
    first = _digests(labels, gates)
    assert len(first[0]) == 2 and len(first[2]) == 2
    assert _digests(shuffled, gates) == first
    assert _digests(["x"] * n, gates) == first
