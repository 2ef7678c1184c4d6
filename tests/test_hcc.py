"""The hand-coded FSM: transitions on synthetic perceptions, no state leak, aliasing, roles."""

from __future__ import annotations

import math

import numpy as np
import pytest

from protocols import ExpertOutput
from protocols.aibo import NOT_SEEN, blob_slice, decode_indicator
from simulator.aliasing import conflicting, measure_aliasing
from simulator.controllers.hcc import HCC, LABELS, HeadModel, coarse_label
from simulator.controllers.transitioner import choose_expert
from simulator.episodes import SoccerSim, Trace, run_episode

LOOK = math.radians(-15.0)


def percept(
    ball: tuple[float, float, float] = NOT_SEEN,
    goal: tuple[float, float, float] = NOT_SEEN,
    head: tuple[float, float, float] = (LOOK, 0.0, 0.0),
) -> np.ndarray:
    x = np.zeros(23)
    for k in range(6):
        x[3 * k : 3 * k + 3] = NOT_SEEN
    x[blob_slice("ball")] = ball
    x[blob_slice("blue_goal")] = goal
    x[18:21] = head
    x[21:23] = (0.0, math.radians(20))
    return x


def test_nothing_seen_means_seek_turning_in_place_in_the_look_pose() -> None:
    h = HCC()
    for _ in range(60):
        y, label = h.act(percept())
        assert label == "seek_left"
        assert y[0] == 0 and y[2] == h.p.seek_turn
        assert decode_indicator(y[8]) == "none"
        assert tuple(y[3:6]) == (h.p.look_tilt, 0.0, h.p.look_nod)


def test_seek_turns_towards_the_ball_s_remembered_side() -> None:
    h = HCC()
    h.act(percept(ball=(0.8, 0.0, 0.1)))  # one glimpse, to the right: not enough to approach
    y, label = h.act(percept())
    assert label == "seek_left"  # the side is chosen at entry only
    h._go(h._seek_side())
    y, label = h.act(percept())
    assert label == "seek_right" and y[2] == -h.p.seek_turn


def test_seek_wanders_after_a_full_turn_without_the_ball() -> None:
    h = HCC()
    ticks = int((2 * math.pi + 0.5) / h.p.seek_turn * h.p.hz) + 2
    out = [h.act(percept()) for _ in range(ticks)]
    y, label = out[-1]
    assert label == "wander" and y[0] == h.p.wander_speed and y[2] == 0


def test_every_policy_is_a_function_of_the_perception() -> None:
    """Same subtask, same perception -> same action, whatever the FSM remembers (issue 13)."""
    a, b = HCC(), HCC()
    for _ in range(50):  # b accumulates odometry, timers, bearings
        b.act(percept(goal=(0.5, 0.2, 0.3)))
    b.act(percept(ball=(-0.7, -0.2, 0.1)))
    x_set = [percept(), percept(ball=(0.2, -0.3, 0.1)), percept(goal=(-0.4, 0.2, 0.3))]
    for label in LABELS:
        for x in x_set:
            np.testing.assert_array_equal(a.policy(label, x), b.policy(label, x))
    with pytest.raises(ValueError, match="unknown subtask"):
        a.policy("dance", percept())


def _near_ball() -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """A ball 0.22 m in front of the trunk centre, seen from a head tilted down 55 degrees."""
    head = HeadModel()
    tilt = math.radians(-55)
    pos, rot = head.camera_pose(tilt, 0.0, 0.0)
    d = rot.T @ (np.array([0.22, 0.0, 0.042]) - pos)
    return (0.0, head.fn * d[2] / d[0], 0.4), (tilt, 0.0, 0.0)


def test_ball_seen_for_two_ticks_starts_approach_and_a_close_ball_the_held_trap() -> None:
    h = HCC()
    far = (0.0, -0.1, 0.1)
    assert h.act(percept(ball=far))[1] == "seek_left"
    y, label = h.act(percept(ball=far))
    assert label == "approach" and y[0] > 0.1  # walks to a ball ahead
    near, head = _near_ball()
    y, label = h.act(percept(ball=near, head=head))
    assert label == "trap" and decode_indicator(y[8]) == "trap"
    out = [h.act(percept()) for _ in range(h.n_trap + 1)]
    # the indicator is held for exactly the motion (one more would start a second trap)
    assert [lab for _, lab in out[: h.n_trap - 1]] == ["trap"] * (h.n_trap - 1)
    assert all(decode_indicator(y[8]) == "trap" for y, _ in out[: h.n_trap - 1])
    assert out[-1][1] in ("aim_left", "aim_right")
    assert decode_indicator(out[-1][0][8]) == "none"


def _aiming(state: str = "aim_left") -> HCC:
    h = HCC()
    h.state = state
    return h


def test_aim_turns_to_the_goal_and_kicks_when_centred() -> None:
    h = _aiming()
    y, label = h.act(percept(goal=(0.6, 0.2, 0.3)))  # goal to the right
    assert label == "aim" and y[2] < 0 and decode_indicator(y[8]) == "none"
    labels = [h.act(percept(goal=(0.0, 0.2, 0.3)))[1] for _ in range(h.p.aim_settle_ticks)]
    assert labels[-1] == "kick"  # centred for aim_settle_ticks
    kicks = [h.act(percept(goal=(0.0, 0.2, 0.3))) for _ in range(h.n_kick - 1)]
    assert all(decode_indicator(y[8]) == "kick" and lab == "kick" for y, lab in kicks)
    h.act(percept())
    assert h.state in ("seek_left", "seek_right")
    # the released ball in view: the kick's indicator is off (it is the approach's perception)
    y = h.policy("kick", percept(ball=(0.0, -0.2, 0.1)))
    assert decode_indicator(y[8]) == "none"


def test_aim_without_the_goal_pivots_towards_its_remembered_side() -> None:
    h = _aiming()
    h.act(percept(goal=(0.9, 0.2, 0.3)))  # glimpse: right
    y, label = h.act(percept())
    assert label == "aim_right" and y[2] == -h.p.aim_turn and y[1] == h.p.aim_side


def test_aim_sees_a_ball_in_front_means_the_trap_failed() -> None:
    h = _aiming()
    for _ in range(16):
        h.act(percept())
    assert h.act(percept(ball=(0.0, -0.3, 0.15)))[1] == "approach"


def test_aim_times_out_into_a_kick() -> None:
    h = _aiming()
    labels = [h.act(percept())[1] for _ in range(int(h.p.aim_timeout * h.p.hz) + 2)]
    assert labels[-1] == "kick"


def test_tail_and_head_pose_do_not_reveal_seek_aim_or_kick() -> None:
    """The tail command is a constant; seek, aim and kick all hold the look pose."""
    ys = [HCC().policy(s, percept()) for s in ("seek_left", "aim_left", "kick", "wander")]
    for y in ys[1:]:
        np.testing.assert_array_equal(ys[0][3:8], y[3:8])
    assert {coarse_label(s) for s in LABELS} == {"seek", "trap", "aim", "kick"}


def test_ball_position_estimate_matches_the_world() -> None:
    sim = SoccerSim(vision="rendered")
    try:
        errs = []
        for pose, ball, tilt in [
            ((0.0, 0.0, 0.0), (0.5, 0.1), -0.5),
            ((0.0, 0.0, 0.0), (1.5, -0.2), -0.2),
            ((1.0, 1.0, 2.0), (0.8, 1.25), -0.9),
        ]:
            sim.world.reset(pose, ball, np.random.default_rng(0), np.random.default_rng(0))
            sim.world.head = np.array([tilt, 0.0, 0.0])
            sim.world._apply_joints()
            x = sim.perceive()
            b = x[blob_slice("ball")]
            assert b[2] > 0
            est = HeadModel().ball_position(b[0], b[1], b[2], *x[18:21], 0.042)
            true = sim.world.ball_in_robot_frame()[:2]
            errs.append(math.dist(est, true))
        assert max(errs) < 0.03  # metres (0.3-1.5 m away), vision noise included
    finally:
        sim.close()


def test_hcc_scores_from_the_easy_start_in_process() -> None:
    sim = SoccerSim(vision="fast")
    try:
        tr = Trace()
        res = run_episode(sim, HCC(), 0, seed=2, trace=tr)
    finally:
        sim.close()
    assert res.outcome == "goal"
    labels = list(dict.fromkeys(coarse_label(s) for s in tr.labels))  # first appearance
    assert labels == ["seek", "trap", "aim", "kick"]


# --- aliasing ----------------------------------------------------------------------------


def test_aliasing_measure_on_constructed_data() -> None:
    x = percept()
    turn_left, turn_right, kick = np.zeros(9), np.zeros(9), np.zeros(9)
    turn_left[2], turn_right[2], kick[8] = 1.5, -1.5, 1.0
    X = np.array([x, x + 0.01, x, x + 0.02, x + 5.0])
    Y = np.array([turn_left, turn_right, kick, turn_left, kick])
    labels = ["seek_left", "aim_left", "kick", "seek_left", "aim_left"]
    rep = measure_aliasing(X, Y, labels, episodes=[0, 1, 2, 3, 4])
    assert rep["pairs"] == 6  # the last point is far from the rest
    pp = rep["per_subtask_pair"]
    assert pp["seek_left/seek_left"] == {"pairs": 1, "conflicts": 0, "fraction": 0.0}
    assert pp["seek_left/aim_left"]["fraction"] == 1.0
    assert pp["seek_left/kick"]["fraction"] == 1.0
    assert rep["within_subtask_conflict_by_subtask"] == {"seek_left": 0.0}
    assert rep["cross_subtask_conflict_fraction"] == 1.0
    assert conflicting(turn_left, turn_left + 0.01).tolist() == [False]


def test_aliasing_ignores_temporal_neighbours() -> None:
    x = percept()
    X = np.array([x] * 5)
    Y = np.zeros((5, 9))
    rep = measure_aliasing(X, Y, ["seek"] * 5, min_gap=3)
    assert rep["pairs"] == 3  # (0,3), (0,4), (1,4)


def test_hcc_demonstrations_show_the_papers_aliasing() -> None:
    """Aim never sees the ball; near-identical inputs across subtasks call for other actions."""
    sim = SoccerSim(vision="fast")
    xs, ys, ls, es = [], [], [], []
    try:
        for k, loc in enumerate((3, 8, 10)):  # starts that seek first
            tr = Trace()
            run_episode(sim, HCC(), loc, seed=0, trace=tr)
            X, Y, L = tr.arrays()
            xs.append(X)
            ys.append(Y)
            ls.append(L)
            es.append(np.full(len(X), k))
    finally:
        sim.close()
    rep = measure_aliasing(
        np.concatenate(xs), np.concatenate(ys), np.concatenate(ls), np.concatenate(es)
    )
    assert rep["aim_points"] > 30
    assert rep["aim_ball_seen_fraction"] == 0.0
    assert rep["aim_ball_and_goal_seen_fraction"] == 0.0
    assert rep["cross_subtask_pairs"] > 10
    assert rep["cross_subtask_conflict_fraction"] > 0.8


# --- transitioner expert choice ----------------------------------------------------------


def _e(i: int, p: float, label: str) -> ExpertOutput:
    return ExpertOutput(i, p, np.full(9, float(i)), np.ones(9), 10, label)


def test_choose_expert_by_label_then_fallbacks() -> None:
    mm = (_e(1, 0.5, "trap"), _e(2, 0.2, "aim"), _e(3, 0.3, "aim"))
    assert choose_expert(mm, "aim") == (mm[2], "label")
    assert choose_expert(mm, "trap") == (mm[0], "label")
    assert choose_expert(mm, "kick") == (mm[0], "fallback_top")
    assert choose_expert((), "kick") == (None, "fallback_mean")
    tie = (_e(5, 0.5, "seek"), _e(4, 0.5, "seek"))
    assert choose_expert(tie, "seek")[0] is tie[1]


@pytest.mark.parametrize("bad", [np.zeros(22), np.zeros(24)])
def test_hcc_rejects_wrong_dimension(bad: np.ndarray) -> None:
    with pytest.raises(ValueError):
        HCC().act(bad)
