"""The segmentation history (roger_daemon/learner/history.py): settling the prefix where the
particles' lineages meet changes no assignment, keeps memory per point at one id, and gives
canonical state dicts; schema-2 states (the full table) load as the same model."""

from __future__ import annotations

import json

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from roger_daemon.learner import Roger, RogerParams, load_model
from roger_daemon.learner.history import SegmentationHistory
from roger_daemon.learner.synthetic import subtask_stream

WIDTH = 4


def naive_trace(anc: np.ndarray, eid: np.ndarray, last: int) -> np.ndarray:
    """The oracle: the full table chased back from particle ``last`` of the final row."""
    out = np.empty(len(anc), dtype=np.int64)
    j = last
    for t in range(len(anc) - 1, -1, -1):
        out[t] = eid[t, j]
        j = anc[t, j]
    return out


@st.composite
def ancestries(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray, list[bool]]:
    """A random table of survivors: row t has ``alive_t`` survivors, each descending from one
    of the ``alive_{t-1}`` particles of the row before, with random expert ids."""
    n = draw(st.integers(1, 300))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    concentrated = draw(st.booleans())  # few ancestors (lineages meet soon) or many
    anc = np.full((n, WIDTH), -1, dtype=np.int32)
    eid = np.full((n, WIDTH), -1, dtype=np.int64)
    prev = 1
    for t in range(n):
        alive = int(rng.integers(1, WIDTH + 1))
        pool = min(prev, 2) if concentrated else prev
        anc[t, :alive] = rng.integers(0, pool, alive)
        eid[t, :alive] = rng.integers(0, 6, alive)
        prev = alive
    settles = draw(st.lists(st.booleans(), min_size=n, max_size=n))
    return anc, eid, settles


@settings(max_examples=60, deadline=None)
@given(ancestries())
def test_settling_changes_no_assignment_and_state_is_canonical(
        case: tuple[np.ndarray, np.ndarray, list[bool]]) -> None:
    anc, eid, settles = case
    eager, lazy = SegmentationHistory(WIDTH), SegmentationHistory(WIDTH)
    for t in range(len(anc)):
        alive = int(np.count_nonzero(eid[t] >= 0))
        for h in (eager, lazy):
            h.append(anc[t, :alive], eid[t, :alive])
        if settles[t]:
            eager.settle()
    alive = int(np.count_nonzero(eid[-1] >= 0))
    for j in range(alive):
        want = naive_trace(anc, eid, j)
        np.testing.assert_array_equal(eager.assignments(j), want)
        np.testing.assert_array_equal(lazy.assignments(j), want)
    np.testing.assert_array_equal(eager.last_ids(), eid[-1])
    a, b = eager.state(), lazy.state()
    assert a.keys() == b.keys()
    for key in a:
        np.testing.assert_array_equal(a[key], b[key])
    # a schema-2 table (no settled prefix) loads as the same history
    old = SegmentationHistory.from_state(WIDTH, None, anc, eid)
    restored = SegmentationHistory.from_state(WIDTH, a["history_settled"],
                                              a["history_ancestor"], a["history_expert"])
    for h in (old, restored):
        for j in range(alive):
            np.testing.assert_array_equal(h.assignments(j), naive_trace(anc, eid, j))


def test_settle_keeps_the_rows_since_the_lineages_met() -> None:
    h = SegmentationHistory(2)
    h.append([0], [5])          # t=0: one particle
    h.append([0], [7])          # t=1: one particle
    h.append([0, 0], [7, 8])    # t=2: both from particle 0 of t=1
    h.append([0, 1], [7, 8])    # t=3: lineages apart from here back to t=1
    h.settle()
    assert (h.n_settled, h.n_rows) == (1, 3)  # rows 1-3 kept: the lineages meet at row 1
    np.testing.assert_array_equal(h.assignments(0), [5, 7, 7, 7])
    np.testing.assert_array_equal(h.assignments(1), [5, 7, 8, 8])
    h.append([1], [8])          # t=4: only the second lineage survives
    h.settle()
    assert (h.n_settled, h.n_rows) == (4, 1)
    np.testing.assert_array_equal(h.assignments(0), [5, 7, 8, 8, 8])


def learn(model: Roger, x: np.ndarray, y: np.ndarray) -> None:
    for xi, yi in zip(x, y, strict=True):
        model.learn_one(xi, yi)


def test_memory_per_point_is_one_id_once_the_lineages_meet() -> None:
    rng = np.random.default_rng(0)
    h = SegmentationHistory(10)
    n = 50_000
    for _ in range(n):  # resampling that keeps copies of the two heaviest particles
        h.append(rng.integers(0, 2, 10), rng.integers(0, 5, 10))
    assert len(h) == n and h.n_rows < 64
    # the full table would hold 12 bytes per particle per point: 120 B, 6 MB here
    assert h.nbytes < 2 * 8 * n + 12 * 10 * 128, h.nbytes


def test_roger_history_settles_and_schema_2_migrates() -> None:
    s = subtask_stream(1500)
    model = Roger(23, 9, RogerParams(beta=30), seed=3)
    learn(model, s.x[:1200], s.y[:1200])
    state = model.state_dict()
    kept = state["history_ancestor"].shape[0]
    assert state["history_settled"].size + kept == 1200
    assert state["history_settled"].size > 0  # the particles' lineages met
    # the same state in schema 2: the full (N, P) table, settled rows as one lineage
    settled = state["history_settled"]
    old = dict(state)
    old["history_ancestor"] = np.concatenate(
        [np.zeros((settled.size, 10), dtype=np.int32), state["history_ancestor"]])
    old["history_expert"] = np.concatenate(
        [np.repeat(settled[:, None], 10, axis=1), state["history_expert"]])
    del old["history_settled"]
    meta = json.loads(str(old["meta"]))
    meta["schema"] = 2
    old["meta"] = np.array(json.dumps(meta))
    migrated = load_model(old)
    np.testing.assert_array_equal(migrated.assignments(), model.assignments())
    resaved = migrated.state_dict()
    for key in state:
        np.testing.assert_array_equal(resaved[key], state[key], err_msg=key)
    learn(model, s.x[1200:], s.y[1200:])
    learn(migrated, s.x[1200:], s.y[1200:])
    np.testing.assert_array_equal(migrated.assignments(), model.assignments())
