"""The majority-label rule's incremental form (roger_daemon/labels.py: LabelTally): the same
labels as the whole-history rule at every step of a learning model, as labels are added to the
vocabulary, and after the model is replaced."""

from __future__ import annotations

import numpy as np
import pytest

from roger_daemon.labels import LabelTally, majority_labels_coded
from roger_daemon.learner import Roger, RogerParams
from roger_daemon.learner.synthetic import subtask_stream

VOCAB = ["", "aim", "kick", "seek", "trap"]


def test_tally_equals_the_whole_history_rule_while_learning() -> None:
    s = subtask_stream(700)
    model = Roger(23, 9, RogerParams(beta=20), seed=1)
    rng = np.random.default_rng(0)
    # codes of a growing vocabulary: only "" and "aim" at first, all five from point 300 on
    codes = np.where(np.arange(700) < 300, s.labels % 2, s.labels % 5)
    codes[rng.random(700) < 0.1] = 0  # some points unlabelled
    tally = LabelTally()
    checked = 0
    for i in range(700):
        model.learn_one(s.x[i], s.y[i])
        if i % 7 and i < 690:
            continue
        vocab = VOCAB[:2] if i < 300 else VOCAB
        want = majority_labels_coded(model.assignments(), codes[: i + 1], vocab)
        assert tally.labels(model, codes[: i + 1], vocab) == want, i
        checked += 1
    settled = model.n_learned - model.unsettled_points().size
    assert settled > 600 and tally.counted == 700 and checked > 90
    # another model (a reset): counted afresh, not on top of the old counts
    fresh = Roger(23, 9, RogerParams(beta=20), seed=2)
    for i in range(50):
        fresh.learn_one(s.x[i], s.y[i])
    want = majority_labels_coded(fresh.assignments(), codes[:50], VOCAB)
    assert tally.labels(fresh, codes[:50], VOCAB) == want


@pytest.mark.parametrize("vectorise_above", [0, LabelTally.vectorise_above, 10**9])
def test_tally_equals_the_rule_at_every_step_as_the_map_particle_changes(
        vectorise_above: int) -> None:
    """Checked after every point: the MAP particle (and with it the experts of the unsettled
    points) changes between calls, and experts that lose all their points are forgotten; the
    counts taken point by point or in one vectorised pass alike."""
    s = subtask_stream(400)
    model = Roger(23, 9, RogerParams(beta=15, particles=6), seed=3)
    codes = s.labels % len(VOCAB)
    tally = LabelTally()
    tally.vectorise_above = vectorise_above
    map_changes = 0
    last = None
    for i in range(400):
        model.learn_one(s.x[i], s.y[i])
        now = model.assignments()
        if last is not None and not np.array_equal(now[: len(last)], last):
            map_changes += 1
        last = now
        assert tally.labels(model, codes[: i + 1], VOCAB) == \
            majority_labels_coded(now, codes[: i + 1], VOCAB), i
    assert map_changes >= 3 and tally.counted == 400


def test_a_first_call_on_a_long_history_counts_it_in_one_pass() -> None:
    """The daemon's first prediction after a restart labels a long history at once."""
    s = subtask_stream(500)
    model = Roger(23, 9, RogerParams(beta=15), seed=4)
    codes = s.labels % len(VOCAB)
    for i in range(450):
        model.learn_one(s.x[i], s.y[i])
    tally = LabelTally()
    assert tally.labels(model, codes[:450], VOCAB) == \
        majority_labels_coded(model.assignments(), codes[:450], VOCAB)
    for i in range(450, 500):
        model.learn_one(s.x[i], s.y[i])
        assert tally.labels(model, codes[: i + 1], VOCAB) == \
            majority_labels_coded(model.assignments(), codes[: i + 1], VOCAB), i
