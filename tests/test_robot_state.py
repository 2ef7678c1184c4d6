"""A checkpoint's daemon arrays (:mod:`roger_daemon.daemon.robot_state`): the newest pair
received round-trips, and a checkpoint written before it existed reads as none."""

from __future__ import annotations

import numpy as np
import pytest

from protocols.messages import Dims
from roger_daemon.daemon.robot_state import NEWEST_KEYS, NewestPair, Pair, RobotState

DIMS = Dims(2, 1)


def _state(newest: NewestPair | None) -> RobotState:
    queue = [Pair(np.array([0.5, 1.5]), np.array([2.0]), 1, 7)]
    return RobotState(["seek", "kick"], np.array([0, 1, 1], dtype=np.int32), queue, newest)


def test_the_newest_pair_round_trips() -> None:
    newest = NewestPair(7, np.array([0.5, 1.5]), np.array([2.0]))
    arrays = _state(newest).to_arrays(DIMS)
    assert arrays["newest_pair_x"].shape == (1, 2) and arrays["newest_pair_y"].shape == (1, 1)
    back = RobotState.from_arrays(arrays)
    assert back.newest is not None and back.newest.tick == 7
    assert back.newest.x.tobytes() == newest.x.tobytes()
    assert back.newest.y.tobytes() == newest.y.tobytes()
    assert back.vocab == ["seek", "kick"] and back.n_learned == 3 and len(back.queue) == 1


def test_no_newest_pair_and_an_older_checkpoint_read_as_none() -> None:
    arrays = _state(None).to_arrays(DIMS)
    assert arrays["newest_pair_tick"].shape == (0,) and arrays["newest_pair_x"].shape == (0, 2)
    assert RobotState.from_arrays(arrays).newest is None
    older = {k: v for k, v in _state(NewestPair(7, np.zeros(2), np.zeros(1))).to_arrays(
        DIMS).items() if k not in NEWEST_KEYS}
    back = RobotState.from_arrays(older)
    assert back.newest is None and back.n_learned == 3


def test_newest_pair_arrays_that_do_not_fit_together_are_refused() -> None:
    arrays = _state(NewestPair(7, np.zeros(2), np.zeros(1))).to_arrays(DIMS)
    arrays["newest_pair_x"] = np.zeros((0, 2))  # a tick without its perception
    with pytest.raises(ValueError, match="newest pair has 1 ticks, x of shape"):
        RobotState.from_arrays(arrays)
