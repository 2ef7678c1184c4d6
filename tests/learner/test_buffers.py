"""Reused matrix buffers for copy-on-write copies (:mod:`roger_daemon.learner.engine.buffers`)."""

from __future__ import annotations

import numpy as np
import pytest

from roger_daemon.learner import Roger, RogerParams
from roger_daemon.learner.engine.buffers import BufferPool
from roger_daemon.learner.synthetic import subtask_stream


def test_a_pool_keeps_at_most_its_limit_per_size_and_copies_exactly() -> None:
    pool = BufferPool(limit=1)
    kept, extra = np.full(4, np.nan), np.full(4, np.nan)
    pool.give(kept)
    pool.give(extra)  # over the limit: dropped
    assert len(pool) == 1
    src = np.arange(4.0)
    out = pool.copy_of(src)
    assert out is kept and np.array_equal(out, src)  # the kept buffer, every element written
    fresh = pool.copy_of(src)  # none left: a new array
    assert fresh is not kept and fresh is not src and np.array_equal(fresh, src)
    assert pool.take(4) is None and pool.take(5) is None
    with pytest.raises(ValueError, match="limit must be an integer >= 0, got -1"):
        BufferPool(limit=-1)


def test_reusing_dropped_experts_buffers_changes_no_float() -> None:
    """The same model with the pool off (limit 0) learns the same floats, bit for bit, while
    the pool hands dropped experts' buffers to later copies."""
    s = subtask_stream(200)
    with_pool = Roger(23, 9, RogerParams(beta=20), seed=5)
    without = Roger(23, 9, RogerParams(beta=20), seed=5)
    without.store.pool = BufferPool(limit=0)
    reused = 0
    for x, y in zip(s.x, s.y, strict=True):
        before = len(with_pool.store.pool)
        with_pool.learn_one(x, y)
        without.learn_one(x, y)
        reused += before > len(with_pool.store.pool)
    assert reused > 0 and len(without.store.pool) == 0
    np.testing.assert_array_equal(with_pool.assignments(), without.assignments())
    np.testing.assert_array_equal(with_pool.particle_log_weights(),
                                  without.particle_log_weights())
    for a, b in zip(with_pool.distinct_experts(), without.distinct_experts(), strict=True):
        for m in ("B", "A", "C", "Q", "gram"):
            assert np.array_equal(getattr(a, m), getattr(b, m))
