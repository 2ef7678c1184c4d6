"""The segmentation history (roger_daemon/learner/history.py): settling keeps every assignment
(against a naive trace of the full table), keeps memory at one id per point plus the points on
which surviving lineages disagree, gives canonical state dicts, and schema-2/3 states (the full
table; a settled prefix and a long window) load as the same model."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from roger_daemon.learner import Roger, RogerParams, load_model
from roger_daemon.learner.history import WINDOW, SegmentationHistory
from roger_daemon.learner.synthetic import subtask_stream

from .states import with_schema as older_schema

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


def meeting_row(anc: np.ndarray, alive: int) -> int:
    """Oracle for a schema-3 split: the latest row at which the lineages of the ``alive``
    particles of the last row pass through one particle (-1 if they never do)."""
    on = set(range(alive))
    for t in range(len(anc) - 1, -1, -1):
        if len(on) == 1:
            return t
        on = {int(anc[t, j]) for j in on}
    return -1


@settings(max_examples=80, deadline=None)
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
    traces = np.array([naive_trace(anc, eid, j) for j in range(alive)])
    points = np.random.default_rng(len(anc)).integers(0, len(anc), 20)
    for j in range(alive):
        for h in (eager, lazy):
            np.testing.assert_array_equal(h.assignments(j), traces[j])
            np.testing.assert_array_equal(h.assignments(j, len(anc) // 3),
                                          traces[j][len(anc) // 3:])
            np.testing.assert_array_equal(h.assignments_at(j, points), traces[j][points])
    for h in (eager, lazy):  # off the unsettled points every present lineage agrees
        settled = np.setdiff1d(np.arange(len(anc)), h.unsettled_points())
        assert np.all(traces[:, settled] == traces[:1, settled])
    np.testing.assert_array_equal(eager.last_ids(), eid[-1])
    a, b = eager.state(), lazy.state()
    assert a.keys() == b.keys()
    for key in a:
        np.testing.assert_array_equal(a[key], b[key])
    # a schema-2 table (no settled prefix) and a schema-3 split load as the same history
    old = SegmentationHistory.from_state(WIDTH, None, anc, eid)
    row = max(meeting_row(anc, alive), 0)
    split = SegmentationHistory.from_state(WIDTH, traces[0][:row], anc[row:], eid[row:])
    restored = SegmentationHistory.from_state(
        WIDTH, a["history_settled"], a["history_ancestor"], a["history_expert"],
        a["history_exception_points"], a["history_exception_ids"])
    for h in (old, split, restored):
        for j in range(alive):
            np.testing.assert_array_equal(h.assignments(j), traces[j])
        for key, value in h.state().items():
            np.testing.assert_array_equal(value, a[key])


def test_an_old_disagreement_is_an_exception_until_one_lineage_dies() -> None:
    h = SegmentationHistory(2)
    h.append([0], [5])          # t=0: one particle
    h.append([0, 0], [7, 8])    # t=1: two particles, different experts
    for _ in range(3 * WINDOW):  # both lineages survive, agreeing from here on
        h.append([0, 1], [7, 7])
    h.settle()
    assert h.n_exceptions == 1 and h.n_rows == 1
    np.testing.assert_array_equal(h.unsettled_points(), [1, len(h) - 1])
    np.testing.assert_array_equal(h.assignments(0)[:3], [5, 7, 7])
    np.testing.assert_array_equal(h.assignments(1)[:3], [5, 8, 7])
    h.append([1, 1], [7, 7])    # only the second lineage survives
    h.settle()
    assert h.n_exceptions == 0
    np.testing.assert_array_equal(h.unsettled_points(), [len(h) - 1])
    np.testing.assert_array_equal(h.assignments(0)[:3], [5, 8, 7])


def learn(model: Roger, x: np.ndarray, y: np.ndarray) -> None:
    for xi, yi in zip(x, y, strict=True):
        model.learn_one(xi, yi)


def test_memory_per_point_is_one_id_plus_the_disagreements() -> None:
    rng = np.random.default_rng(0)
    h = SegmentationHistory(10)
    n = 50_000
    for _ in range(n):  # resampling that keeps copies of the two heaviest particles
        h.append(rng.integers(0, 2, 10), rng.integers(0, 5, 10))
    assert len(h) == n and h.n_rows <= WINDOW
    # the full table would hold 12 bytes per particle per point: 120 B, 6 MB here
    assert h.nbytes < 2 * 8 * n + 12 * 10 * 128 + 88 * h.n_exceptions, h.nbytes
    # ten lineages that never meet, disagreeing on one point in a thousand
    apart = SegmentationHistory(10)
    for t in range(n):
        apart.append(np.arange(10), np.arange(10) if t % 1000 == 0 else np.zeros(10))
    apart.settle()
    assert apart.n_exceptions == n // 1000
    assert apart.nbytes < 2 * 8 * n + 12 * 10 * WINDOW + 2 * 88 * (n // 1000), apart.nbytes
    np.testing.assert_array_equal(apart.assignments(3)[:2001:1000], [3, 3, 3])


def older_tables(state: dict[str, np.ndarray], width: int) -> tuple[np.ndarray, np.ndarray]:
    """The settled points as rows of a full table in which every particle descends from
    itself and holds its lineage's ids (the exceptions), followed by the saved window."""
    settled = state["history_settled"]
    eid = np.repeat(settled[:, None], width, axis=1)
    for point, ids in zip(state["history_exception_points"], state["history_exception_ids"],
                          strict=True):
        eid[point, ids >= 0] = ids[ids >= 0]
    anc = np.tile(np.arange(width, dtype=np.int32), (settled.size, 1))
    return (np.concatenate([anc, state["history_ancestor"]]),
            np.concatenate([eid, state["history_expert"]]))


def with_schema(state: dict[str, np.ndarray], schema: int) -> dict[str, np.ndarray]:
    """``state`` as schemas 2 and 3 stored it: no exceptions (the history arrays are set by
    the caller)."""
    return older_schema(state, schema,
                        drop=("history_exception_points", "history_exception_ids"))


def test_roger_history_settles_and_schemas_2_and_3_migrate() -> None:
    s = subtask_stream(1500)
    model = Roger(23, 9, RogerParams(beta=30), seed=3)
    learn(model, s.x[:1200], s.y[:1200])
    state = model.state_dict()
    assert state["history_ancestor"].shape == (1, 10)  # saved settled: the last step only
    assert state["history_settled"].size == 1199
    anc, eid = older_tables(state, 10)
    first = int(state["history_exception_points"][0]) if state["history_exception_points"].size \
        else 1199
    old2 = with_schema(state, 2)  # the full (N, P) table
    del old2["history_settled"]
    old2["history_ancestor"], old2["history_expert"] = anc, eid
    old3 = with_schema(state, 3)  # settled up to the first disagreement, then the table
    old3["history_settled"] = state["history_settled"][:first]
    old3["history_ancestor"], old3["history_expert"] = anc[first:], eid[first:]
    for old in (old2, old3):
        migrated = load_model(old)
        np.testing.assert_array_equal(migrated.assignments(), model.assignments())
        resaved = migrated.state_dict()
        for key in state:
            np.testing.assert_array_equal(resaved[key], state[key], err_msg=key)
    learn(model, s.x[1200:], s.y[1200:])
    learn(migrated, s.x[1200:], s.y[1200:])
    np.testing.assert_array_equal(migrated.assignments(), model.assignments())


def test_saving_reads_only_so_threads_may_save_one_model_at_once() -> None:
    """``state`` saves a settled copy and leaves the history as it is: a model saved from
    several threads at once gives every thread the same arrays and keeps its assignments (two
    concurrent settles once counted the window twice: 443 assignments for 411 points)."""
    from concurrent.futures import ThreadPoolExecutor

    from roger_daemon.daemon.checkpoint import array_digest

    s = subtask_stream(150)
    model = Roger(23, 9, RogerParams(beta=20), seed=2)
    learn(model, s.x, s.y)
    hist = model.history
    assert hist.n_rows > 1  # a window that saving settles
    before = (hist.n_settled, hist.n_rows, model.assignments().tolist())
    want = array_digest(model.state_dict())
    assert (hist.n_settled, hist.n_rows) == before[:2]  # saving changed nothing
    with ThreadPoolExecutor(max_workers=4) as pool:
        digests = list(pool.map(lambda _: array_digest(model.state_dict()), range(64)))
    assert set(digests) == {want}
    assert (hist.n_settled, hist.n_rows, model.assignments().tolist()) == before
    assert len(before[2]) == 150
