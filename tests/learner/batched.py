"""A small stream learned with the batched kernels (tests/learner/test_jit_batch.py,
tests/learner/test_jit_owners.py): 160 subtask pairs, beta = 20, so the experts fill and the
batched fused step runs."""

from __future__ import annotations

from roger_daemon.learner import Roger, RogerParams
from roger_daemon.learner.engine import jit
from roger_daemon.learner.synthetic import subtask_stream


def learn_stream(threads: int, points: int = 160) -> Roger:
    """A model after ``points`` pairs of the seed-4 subtask stream, on ``threads`` threads."""
    jit.set_threads(threads)
    s = subtask_stream(points, seed=4)
    model = Roger(23, 9, RogerParams(beta=20), seed=3)
    for x, y in zip(s.x, s.y, strict=True):
        model.learn_one(x, y)
    return model
