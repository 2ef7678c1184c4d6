"""One buffer per expert (roger_daemon/learner/engine/jit_slab.py): the views an expert takes of its
slab and the views the compiled kernels take are the same memory, and the slab carries the
whole expert through a copy, a growth, a restore and the buffer pool."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from roger_daemon.learner.engine import jit
from roger_daemon.learner.engine.buffers import BufferPool
from roger_daemon.learner.engine.jit_slab import ALIGN, HEADER, slab_offsets
from roger_daemon.learner.kernel import RBFKernel
from roger_daemon.learner.sogp import SparseOnlineGP


def _expert(d_x: int, d_y: int, capacity: int, points: int, *, prior_mean: bool,
            seed: int = 0) -> SparseOnlineGP:
    rng = np.random.default_rng(seed)
    gp = SparseOnlineGP(d_x, d_y, RBFKernel(0.7, d_x), 0.1, capacity, 1e-6,
                        prior_mean=prior_mean)
    for _ in range(points):
        gp.update(rng.uniform(-1, 1, d_x), rng.normal(size=d_y))
    return gp


def _start(view: np.ndarray, slab: np.ndarray) -> int:
    """Where ``view`` starts in ``slab``, in floats."""
    offset = view.__array_interface__["data"][0] - slab.__array_interface__["data"][0]
    assert offset % 8 == 0
    return offset // 8


@settings(max_examples=40, deadline=None)
@given(alloc=st.integers(0, 40), d_x=st.integers(1, 9), d_y=st.integers(1, 5),
       prior=st.booleans())
def test_the_offsets_keep_the_parts_apart_and_aligned(alloc: int, d_x: int, d_y: int,
                                                       prior: bool) -> None:
    """Each part starts on a multiple of ``ALIGN`` floats after the header and ends before
    the next one starts."""
    a_cols = d_y + prior
    c, q, b, a, m, end = slab_offsets(alloc, d_x, a_cols, d_y)
    packed = alloc * (alloc + 1) // 2
    assert c == HEADER and HEADER >= 4
    for start in (c, q, b, a, m):
        assert start % ALIGN == 0
    assert c + packed <= q and q + packed <= b and b + alloc * d_x <= a
    assert a + alloc * a_cols <= m and end == m + d_y


@pytest.mark.parametrize(("points", "prior"), [(1, False), (5, True), (12, False), (12, True)])
def test_the_kernels_views_are_the_experts_own(points: int, prior: bool) -> None:
    """:func:`.jit_evaluate.slab_views` reads the header and returns views of the very memory
    the expert's ``_Cp``, ``_Qp``, ``_B``, ``_A`` and ``_m`` are, with their shapes."""
    jit.warm_up()
    gp = _expert(3, 2, 12, points, prior_mean=prior, seed=points)
    got = jit.slab_views(gp.slab)
    for mine, theirs in zip((gp._Cp, gp._Qp, gp._B, gp._A, gp._m), got, strict=True):
        assert theirs.shape == mine.shape
        assert _start(theirs, gp.slab) == _start(mine, gp.slab)
        np.testing.assert_array_equal(theirs, mine)
    assert tuple(gp.slab[:4]) == (gp.alloc, gp.a_cols, 3, 2)


def test_a_copy_a_growth_and_a_restore_carry_the_whole_expert() -> None:
    """A copy (with and without the pool) and a restore from the expert's matrices give the
    same predictions and own their slab; buffers grown from 8 to 12 basis vectors keep every
    matrix and the prior mean, with the header in step with the new layout."""
    gp = _expert(3, 2, 12, 8, prior_mean=True, seed=5)
    assert gp.alloc == 8
    x = np.array([0.2, -0.4, 0.1])
    pool = BufferPool(limit=2)
    donor = _expert(3, 2, 12, 8, prior_mean=True, seed=6)
    donor.release(pool)
    pending: list[tuple[np.ndarray, np.ndarray]] = []
    pooled = gp.copy(pool, pending)
    assert pooled.slab is donor.slab and len(pending) == 1
    np.copyto(pending[0][1], pending[0][0])
    plain = gp.copy()
    restored = SparseOnlineGP(3, 2, gp.kernel, 0.1, 12, 1e-6, prior_mean=True)
    restored.load(gp.B, gp._A[: gp.n], gp.C, gp.Q, gp.n_points, alloc=gp.alloc,
                  mean=gp.mean_offset)
    for other in (pooled, plain, restored):
        assert not np.shares_memory(other.slab, gp.slab)
        assert other.predict(x)[0].tolist() == gp.predict(x)[0].tolist()
        assert other.predict(x)[1] == gp.predict(x)[1]
    grown = gp.copy()
    before = (grown.B.copy(), grown._A[: grown.n].copy(), grown.C, grown.Q, grown.mean_offset)
    grown._grow(grown.n + 1)  # the 9th basis vector's room: buffers for 12
    assert grown.alloc == 12 and tuple(grown.slab[:4]) == (12, 3, 3, 2)
    after = (grown.B, grown._A[: grown.n], grown.C, grown.Q, grown.mean_offset)
    for old, new in zip(before, after, strict=True):
        np.testing.assert_array_equal(new, old)
    got = jit.slab_views(grown.slab)
    np.testing.assert_array_equal(got[2][: grown.n], before[0])
    np.testing.assert_array_equal(got[4], before[4])


def test_a_deep_copy_of_a_model_learns_as_the_model_does() -> None:
    """``copy.deepcopy`` of a learning model: each expert's buffers stay views of its own slab
    (the batched kernels read the slab), so the copy learns the next pairs to the same bits as
    the original, and the original is untouched by the copy's learning."""
    from roger_daemon.daemon.checkpoint import array_digest
    from roger_daemon.learner import Roger, RogerParams
    from roger_daemon.learner.synthetic import subtask_stream

    jit.set_threads(2)
    s = subtask_stream(120, seed=4)
    model = Roger(s.x.shape[1], s.y.shape[1], RogerParams(beta=12), seed=3)
    for i in range(80):
        model.learn_one(s.x[i], s.y[i])
    twin = copy.deepcopy(model)
    before = array_digest(model.state_dict())
    for gp in twin.distinct_experts():
        views = jit.slab_views(gp.slab)
        assert all(np.shares_memory(view, gp.slab) for view in (gp._Cp, gp._B, gp._m))
        np.testing.assert_array_equal(views[2], gp._B)
    for i in range(80, 120):
        twin.learn_one(s.x[i], s.y[i])
    assert array_digest(model.state_dict()) == before
    for i in range(80, 120):
        model.learn_one(s.x[i], s.y[i])
    assert array_digest(twin.state_dict()) == array_digest(model.state_dict())
