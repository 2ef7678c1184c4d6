"""The DPA's averaging measure (simulator/experiment/averaging.py) against exact cases, the DPA
node's trace file, and the results block that counts the failures by averaging."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pytest

from protocols import Perception
from protocols.aibo import DIMS, encode_indicator
from simulator.experiment.averaging import AVERAGED_EPISODE_SHARE, MultimapNeighbourhood
from simulator.experiment.dpa_node import CommandTrace, read_trace
from simulator.experiment.report import controller_block


def _two_branches(n: int = 200, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every perception demonstrated twice: once turning left at 1.5 rad/s, once right."""
    x = np.random.default_rng(seed).uniform(-1, 1, size=(n, DIMS.x))
    left = np.zeros((n, DIMS.y))
    left[:, 2] = 1.5
    right = left.copy()
    right[:, 2] = -1.5
    return np.vstack([x, x]), np.vstack([left, right]), x


def test_the_mean_of_two_demonstrated_turns_averages_on_every_tick() -> None:
    xs, ys, x = _two_branches()
    hood = MultimapNeighbourhood(xs, ys)
    blend = np.zeros((len(x), DIMS.y))  # (1.5 + -1.5) / 2: no turn, none of the two actions
    aliased, averaged = hood.averaged_ticks(x, blend)
    assert aliased.all() and averaged.all()
    assert hood.episode_summary(x, blend) == {"aliased_share": 1.0, "averaged_share": 1.0}


def test_a_demonstrated_branch_is_not_averaging() -> None:
    xs, ys, x = _two_branches()
    hood = MultimapNeighbourhood(xs, ys)
    left = ys[: len(x)]
    aliased, averaged = hood.averaged_ticks(x, left)
    assert aliased.all() and not averaged.any()


def test_a_wrong_command_on_a_unimap_is_an_error_not_averaging() -> None:
    """One demonstrated action per perception: nothing to average, whatever the command."""
    xs, ys, x = _two_branches()
    hood = MultimapNeighbourhood(xs[: len(x)], ys[: len(x)])  # the left branch only
    wrong = np.zeros((len(x), DIMS.y))
    wrong[:, 2] = -2.0
    aliased, averaged = hood.averaged_ticks(x, wrong)
    assert not aliased.any() and not averaged.any()


def test_a_blended_action_indicator_averages_kick_and_turn() -> None:
    """Kick (stand, indicator +1) and seek (turn, indicator 0) at the same perception: standing
    with the indicator below the kick threshold (what the DPA did from location 4) is neither;
    the kick itself is one of them."""
    x = np.random.default_rng(1).uniform(-1, 1, size=(50, DIMS.x))
    kick = np.zeros((50, DIMS.y))
    kick[:, 8] = encode_indicator("kick")
    seek = np.zeros((50, DIMS.y))
    seek[:, 2] = 1.5
    hood = MultimapNeighbourhood(np.vstack([x, x]), np.vstack([kick, seek]))
    blend = np.zeros((50, DIMS.y))
    blend[:, 8] = 0.35 * encode_indicator("kick")
    assert hood.averaged_ticks(x, blend)[1].all()
    assert not hood.averaged_ticks(x, kick)[1].any()


def test_bad_shapes_are_refused() -> None:
    with pytest.raises(ValueError, match="matching non-empty"):
        MultimapNeighbourhood(np.zeros((3, DIMS.x)), np.zeros((2, DIMS.y)))
    xs, ys, x = _two_branches(20)
    with pytest.raises(ValueError, match="20 perceptions but 3 commands"):
        MultimapNeighbourhood(xs, ys).averaged_ticks(x, np.zeros((3, DIMS.y)))


def test_the_dpa_trace_splits_episodes_where_the_episode_clock_restarts(tmp_path: Path
                                                                         ) -> None:
    trace = CommandTrace()
    sent = {}
    tick = 0
    for _episode in range(2):
        for k in range(10):
            x = np.full(DIMS.x, float(tick))
            y = np.full(DIMS.y, float(-tick))
            if tick != 13:  # a perception never received: that tick is left out
                trace.perceptions([Perception("aibo", tick, k / 30.0, x=x)])
            trace.command(tick, y + 1.0)
            trace.command(tick, y)  # a re-sent tick: its last command counts
            sent[tick] = (x, y)
            tick += 1
    path = tmp_path / "trace.npz"
    trace.write(str(path))
    episodes = read_trace(path)
    assert [len(x) for x, _ in episodes] == [10, 9]
    for x, y in episodes:
        for row_x, row_y in zip(x, y, strict=True):
            want_x, want_y = sent[int(row_x[0])]
            np.testing.assert_array_equal(row_x, want_x)
            np.testing.assert_array_equal(row_y, want_y)


def test_the_dpa_node_accepts_a_trace_path() -> None:
    from simulator.experiment.dpa_node import configure

    p = argparse.ArgumentParser()
    configure(p)
    assert p.parse_args(["--trace", "t.npz"]).trace == "t.npz"
    assert p.parse_args([]).trace is None


def test_the_results_count_failures_by_averaging_per_mode() -> None:
    def ep(outcome: str, share: float | None, path: float = 2.0) -> dict[str, object]:
        e: dict[str, object] = {"outcome": outcome, "success": outcome == "goal",
                                "path_m": path, "traps": 0, "traps_ok": 0, "kicks": 0}
        if share is not None:
            e["averaged_share"] = share
        return e

    high = AVERAGED_EPISODE_SHARE + 0.5
    block = controller_block([ep("timeout", high, 0.1), ep("timeout", 0.01, 0.1),
                              ep("timeout", high), ep("goal", high), ep("timeout", None)])
    a = block["averaging"]
    assert a["failed_episodes_measured"] == 3 and a["failed_by_averaging"] == 2
    assert a["by_failure_mode"]["stands still"] == {
        "episodes": 2, "by_averaging": 1, "mean_averaged_share": round((high + 0.01) / 2, 3)}
    assert a["by_failure_mode"]["never traps"]["by_averaging"] == 1
    assert "averaging" not in controller_block([ep("timeout", None)])
