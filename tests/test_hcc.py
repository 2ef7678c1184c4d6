"""The hand-coded FSM: transitions on synthetic perceptions, no state leak, aliasing, roles."""

from __future__ import annotations

import math

import numpy as np
import pytest

from protocols import ExpertOutput
from protocols.aibo import NOT_SEEN, blob_slice, decode_indicator
from simulator.aliasing import conflicting, measure_aliasing
from simulator.episodes import SoccerSim, Trace, run_episode
from simulator.hcc import HCC, HeadModel
from simulator.hcc_node import choose_expert

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


def test_nothing_seen_means_seek_turning_in_place_with_a_head_scan() -> None:
    h = HCC()
    pans = []
    for _ in range(60):  # one head-scan period
        y, label = h.act(percept())
        assert label == "seek"
        assert y[0] == 0 and abs(y[2]) == h.p.seek_turn
        assert decode_indicator(y[8]) == "none"
        pans.append(y[4])
    assert max(pans) > 0.5 and min(pans) < -0.5  # the head sweeps


def test_seek_wanders_after_a_full_turn_without_the_ball() -> None:
    h = HCC()
    ticks = int((2 * math.pi + 0.5) / h.p.seek_turn * h.p.hz) + 2
    ys = [h.act(percept())[0] for _ in range(ticks)]
    assert ys[-1][0] == h.p.wander_speed and ys[-1][2] == 0


def test_ball_seen_for_two_ticks_starts_trap_and_a_close_ball_triggers_the_motion() -> None:
    h = HCC()
    far = (0.0, -0.1, 0.1)
    assert h.act(percept(ball=far))[1] == "seek"
    y, label = h.act(percept(ball=far))
    assert label == "trap" and y[0] > 0.1  # walks to a ball ahead
    # ball right under the nose: image y where the ray from the look pose meets the floor at
    # 0.22 m in front of the trunk centre
    head = HeadModel()
    tilt = math.radians(-55)
    pos, rot = head.camera_pose(tilt, 0.0, 0.0)
    d = rot.T @ (np.array([0.22, 0.0, 0.042]) - pos)
    near = (0.0, head.fn * d[2] / d[0], 0.4)
    y, label = h.act(percept(ball=near, head=(tilt, 0.0, 0.0)))
    assert label == "trap" and decode_indicator(y[8]) == "trap"
    indicators = [decode_indicator(h.act(percept())[0][8]) for _ in range(30)]
    assert indicators[:22].count("trap") == 22  # held for the motion, ball out of view
    assert h.state == "aim"


def _aiming() -> HCC:
    h = HCC()
    h.state = "aim"
    return h


def test_aim_turns_to_the_goal_and_kicks_when_centred() -> None:
    h = _aiming()
    y, label = h.act(percept(goal=(0.6, 0.2, 0.3)))  # goal to the right
    assert label == "aim" and y[2] < 0 and decode_indicator(y[8]) == "none"
    labels = [h.act(percept(goal=(0.0, 0.2, 0.3)))[1] for _ in range(4)]
    assert labels[-1] == "kick"
    kicks = [h.act(percept(goal=(0.0, 0.2, 0.3)))[0][8] for _ in range(20)]
    assert all(decode_indicator(v) == "kick" for v in kicks)
    for _ in range(10):
        h.act(percept())
    assert h.state == "seek"


def test_aim_without_the_goal_turns_towards_its_remembered_side() -> None:
    h = _aiming()
    h.act(percept(goal=(0.9, 0.2, 0.3)))  # glimpse: right
    y, label = h.act(percept())
    assert label == "aim" and y[2] == -h.p.aim_turn


def test_aim_sees_a_ball_in_front_means_the_trap_failed() -> None:
    h = _aiming()
    for _ in range(16):
        h.act(percept())
    assert h.act(percept(ball=(0.0, -0.3, 0.15)))[1] == "trap"


def test_aim_times_out_into_a_kick() -> None:
    h = _aiming()
    labels = [h.act(percept())[1] for _ in range(int(h.p.aim_timeout * h.p.hz) + 2)]
    assert labels[-1] == "kick"


def test_tail_and_aim_head_pose_do_not_reveal_the_subtask() -> None:
    """The tail follows a state-free clock; the aim head pose is on the seek scan."""
    seek, aim = HCC(), _aiming()
    for _ in range(40):
        ys, ls = seek.act(percept())
        ya, la = aim.act(percept())
        assert (ls, la) == ("seek", "aim")
        np.testing.assert_array_equal(ys[6:8], ya[6:8])
    assert ya[3] == ys[3] and ya[5] == ys[5]  # same tilt and nod; seek's pan sweeps through 0


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
    labels = list(dict.fromkeys(tr.labels))  # order of first appearance
    assert labels == ["seek", "trap", "aim", "kick"]


# --- aliasing ----------------------------------------------------------------------------


def test_aliasing_measure_on_constructed_data() -> None:
    x = percept()
    turn_left, turn_right, kick = np.zeros(9), np.zeros(9), np.zeros(9)
    turn_left[2], turn_right[2], kick[8] = 1.5, -1.5, 1.0
    X = np.array([x, x + 0.01, x, x + 0.02, x + 5.0])
    Y = np.array([turn_left, turn_right, kick, turn_left, kick])
    labels = ["seek", "aim", "kick", "seek", "aim"]
    rep = measure_aliasing(X, Y, labels, episodes=[0, 1, 2, 3, 4])
    assert rep["pairs"] == 6  # the last point is far from the rest
    pp = rep["per_subtask_pair"]
    assert pp["seek/seek"] == {"pairs": 1, "conflicts": 0, "fraction": 0.0}
    assert pp["seek/aim"]["fraction"] == 1.0 and pp["seek/kick"]["fraction"] == 1.0
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
