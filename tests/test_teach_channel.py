"""roger teach's pieces without a browser: the page's input channel, its flood guard, the
learned transitions' learn mask, the table of a prediction, the page's files and config."""

from __future__ import annotations

import json
from collections import Counter

import numpy as np
import pytest

from protocols import ExpertOutput, Prediction
from protocols.aibo import ACTION_NAMES, ACTION_RANGES
from simulator.teach.channel import KEYMAP, MAX_FRAME, REASONS, Guard, Refused, parse

#: a command inside every documented range (the tail's tilt is 5-60 degrees)
VALID = [0.0, 0.0, 0.0, -0.2, 0.0, 0.0, 0.0, 0.3, 0.0]


def _cmd(**kw: object) -> str:
    return json.dumps({"type": "command", "y": VALID, "active": True, **kw})


def test_good_inputs_parse() -> None:
    c = parse(_cmd(tick=4, sent_ms=1.5e12))
    assert c.type == "command" and c.y == tuple(VALID) and c.active and c.tick == 4
    assert parse(json.dumps({"type": "mode", "mode": "correct"})).mode == "correct"
    assert parse(json.dumps({"type": "reset", "location": 12})).location == 12
    assert parse(json.dumps({"type": "reset"})).location is None
    assert parse(json.dumps({"type": "place_ball", "x": 1.0, "y": -0.5})).ball == (1.0, -0.5)
    assert parse(json.dumps({"type": "record", "on": True})).on
    assert parse(json.dumps({"type": "hello", "ticks": True})).ticks
    highs = [hi for _, hi in ACTION_RANGES]
    assert parse(json.dumps({"type": "command", "y": highs})).y == tuple(highs)


@pytest.mark.parametrize(("frame", "reason"), [
    (b"\x00\x01", "binary"),
    ("x" * (MAX_FRAME + 1), "oversized"),
    ("{not json", "not_json"),
    ("[1, 2]", "not_an_object"),
    (json.dumps({"type": "fly"}), "unknown_type"),
    (json.dumps({"mode": "correct"}), "unknown_type"),
    (json.dumps({"type": "mode", "mode": "sleep"}), "bad_field"),
    (json.dumps({"type": "command", "y": [0.0] * 8}), "bad_field"),
    (json.dumps({"type": "command", "y": ["0"] * 9}), "bad_field"),
    (json.dumps({"type": "command", "y": [True] + [0.0] * 8}), "bad_field"),
    ('{"type": "command", "y": [NaN, 0, 0, 0, 0, 0, 0, 0, 0]}', "not_finite"),
    (json.dumps({"type": "command", "y": [1.0] + VALID[1:]}), "out_of_range"),
    (json.dumps({"type": "command", "y": VALID[:8] + [2.0]}), "out_of_range"),
    (json.dumps({"type": "command", "y": VALID[:7] + [0.0, 0.0]}), "out_of_range"),
    (_cmd(active="yes"), "bad_field"),
    (_cmd(tick=-1), "out_of_range"),
    (json.dumps({"type": "reset", "location": 13}), "out_of_range"),
    (json.dumps({"type": "place_ball", "x": 9.0, "y": 0.0}), "out_of_range"),
    (json.dumps({"type": "place_ball", "x": "1", "y": 0.0}), "bad_field"),
])
def test_bad_inputs_are_refused_with_their_reason(frame: str | bytes, reason: str) -> None:
    assert reason in REASONS
    counts: Counter[str] = Counter()
    with pytest.raises(Refused) as err:
        Guard(counts).check(frame)
    assert err.value.reason == reason and counts == Counter({reason: 1})


def test_a_flood_is_refused_past_the_burst_and_passes_again_later() -> None:
    now = [0.0]
    counts: Counter[str] = Counter()
    guard = Guard(counts, rate=100.0, burst=10.0, clock=lambda: now[0])
    taken = sum(guard.take() for _ in range(50))
    assert taken == 10 and counts["flood"] == 40
    now[0] += 0.05  # 5 tokens back
    assert sum(guard.take() for _ in range(10)) == 5


def test_keymap_names_real_action_entries_once_per_key() -> None:
    codes = [c for k in KEYMAP for c in k[0]]
    assert len(codes) == len(set(codes))
    assert {k[2] for k in KEYMAP} <= set(ACTION_NAMES)


def test_fit_fsm_learns_no_transition_on_robot_ticks() -> None:
    """fit_fsm's learn mask: a tick the robot drove advances the memories only."""
    from roger_daemon.fsm import aibo_memory, fit_fsm
    from roger_daemon.learner.prediction import MultimapTable

    class TwoExperts:
        def predict_table(self, x: np.ndarray) -> tuple[None, MultimapTable]:
            means = np.zeros((2, 9))
            means[1, 0] = 0.2
            return None, MultimapTable([3, 7], [0.5, 0.5], means, np.full((2, 9), 0.01), [5, 5])

    rng = np.random.default_rng(0)
    x = rng.uniform(-0.5, 0.5, (40, 23))
    y = np.zeros((40, 9))
    y[20:, 0] = 0.2  # expert 7's command from tick 20 on
    starts = np.zeros(40, dtype=bool)
    starts[0] = True
    taught = np.arange(40) < 20
    every = fit_fsm(TwoExperts(), x, y, starts, aibo_memory())
    masked = fit_fsm(TwoExperts(), x, y, starts, aibo_memory(), learn=taught)
    assert 7 in every.transitions.log_scores(3, np.zeros(every.spec.dim))[0].tolist()
    assert 7 not in masked.transitions.log_scores(3, np.zeros(masked.spec.dim))[0].tolist()
    assert masked.n_observed == every.n_observed == 40


def test_a_prediction_becomes_the_fsm_table_and_nothing_learned_holds_still() -> None:
    from simulator.teach.autonomy import Autonomy, table_of

    e = [ExpertOutput(expert=k, p=p, mean=np.full(9, k / 10), var=np.full(9, 0.1), n=k)
         for k, p in ((2, 0.25), (5, 0.75))]
    pred = Prediction("aibo", 1, 0.0, mean=np.zeros(9), var=np.ones(9), expert=5,
                      multimap=tuple(e))
    t = table_of(pred)
    assert t.expert_ids == [2, 5] and t.gate_probs == [0.25, 0.75] and t.n_points == [2, 5]
    assert t.means.shape == (2, 9) and t.means[1, 0] == 0.5
    x = np.zeros(23)
    x[18:23] = [-0.2, 0.1, 0.0, 0.0, 0.3]
    y, expert, how = Autonomy().act(x, None)
    assert expert == -1 and how.startswith("hold") and np.allclose(y[3:8], x[18:23])
    assert not np.any(y[:3]) and y[8] == 0.0


def test_the_page_files_and_config() -> None:
    from importlib import resources

    from simulator.teach.cli import config_for_page
    from simulator.teach.loop import LoopSettings

    static = resources.files("simulator.teach") / "static"
    html = (static / "index.html").read_text("utf-8")
    assert 'src="teach.js"' in html and 'href="teach.css"' in html
    cfg = config_for_page(LoopSettings(), "learned transitions")
    assert len(cfg["keymap"]) == len(KEYMAP) and cfg["action_names"] == list(ACTION_NAMES)
    assert len(cfg["locations"]) == 13 and cfg["field"]["length"] == 5.4
    json.dumps(cfg)
