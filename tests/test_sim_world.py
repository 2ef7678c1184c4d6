"""The simulated world: walk engine limits, head joints, trap, kick calibration, episodes."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from protocols.aibo import encode_indicator
from simulator.config import SimConfig, SimConfigError, load_config
from simulator.episodes import START_LOCATIONS, SoccerSim, parse_locations
from simulator.world import World

CFG = SimConfig()
DT = CFG.episode.dt


@pytest.fixture(scope="module")
def world() -> World:
    w = World(CFG)
    yield w
    w.close()


def _reset(w: World, pose=(0.0, 0.0, 0.0), ball=(2.0, 1.5), seed: int = 0) -> None:
    w.reset(pose, ball, np.random.default_rng(seed), np.random.default_rng(seed + 100))


def _cmd(fwd: float = 0.0, left: float = 0.0, turn: float = 0.0, ind: str = "none") -> np.ndarray:
    y = np.zeros(9)
    y[:3] = (fwd, left, turn)
    y[3] = math.radians(-15)
    y[8] = encode_indicator(ind)
    return y


def test_walk_is_clipped_to_the_velocity_limits(world: World) -> None:
    w = CFG.walk
    _reset(world, (-2.0, 0.0, 0.0))
    for _ in range(90):  # 3 s at 10x the forward limit
        world.step(_cmd(fwd=2.0))
    x, y, yaw = world.robot_pose()
    ramp = w.max_forward / (w.accel_factor * w.max_forward)  # 0.5 s to full speed
    expected = w.max_forward * (3.0 - ramp / 2)
    assert x + 2.0 == pytest.approx(expected, rel=0.06)  # 5 % seeded execution noise
    assert abs(y) < 0.01 and abs(yaw) < 0.01
    assert world.v[0] == pytest.approx(w.max_forward)


def test_acceleration_is_limited(world: World) -> None:
    w = CFG.walk
    _reset(world)
    world.step(_cmd(fwd=w.max_forward, left=-w.max_side, turn=w.max_turn))
    limits = np.array([w.max_forward, w.max_side, w.max_turn])
    np.testing.assert_allclose(np.abs(world.v), w.accel_factor * limits * DT)
    world.step(_cmd(fwd=-1.0))  # reverse: one tick of deceleration brings it back to 0
    assert world.v[0] == pytest.approx(0.0, abs=1e-12)
    assert world.clip_walk(np.array([-1.0, 1.0, -9.0]))[0] == -w.max_backward


def test_walk_directions_follow_the_heading(world: World) -> None:
    _reset(world, (0.0, 0.0, math.pi / 2))
    for _ in range(60):
        world.step(_cmd(fwd=0.2))
    x, y, yaw = world.robot_pose()
    assert y > 0.25 and abs(x) < 0.02 and yaw == pytest.approx(math.pi / 2, abs=0.02)
    _reset(world, (0.0, 0.0, 0.0))
    for _ in range(60):
        world.step(_cmd(left=0.15))
    x, y, _ = world.robot_pose()
    assert y > 0.2 and abs(x) < 0.02
    _reset(world, (0.0, 0.0, 0.0))
    for _ in range(30):
        world.step(_cmd(turn=5.0))
    _, _, yaw = world.robot_pose()
    ramp = 0.5  # seconds to full turn speed
    assert yaw == pytest.approx(CFG.walk.max_turn * (1.0 - ramp / 2), rel=0.08)


def test_head_moves_within_range_and_speed(world: World) -> None:
    _reset(world)
    y = _cmd()
    y[3:6] = (-3.0, 3.0, 3.0)  # far outside every range
    world.step(y)
    r = CFG.robot
    tilt0 = math.radians(-15)
    assert world.head[0] == pytest.approx(tilt0 - r.tilt_speed * DT)
    assert world.head[1] == pytest.approx(r.pan_speed * DT)
    for _ in range(30):
        world.step(y)
    np.testing.assert_allclose(
        world.joint_angles()[:3], np.radians([r.tilt_range[0], r.pan_range[1], r.nod_range[1]])
    )


def test_camera_link_follows_the_head_model(world: World) -> None:
    from simulator.controllers.hcc import HeadModel

    head = HeadModel(CFG.robot, CFG.camera)
    _reset(world, (0.5, -0.3, 0.7))
    world.head = np.array([-0.5, 0.4, 0.2])
    world._apply_joints()
    pos, rot = world.camera_pose()
    bpos, brot = head.camera_pose(*world.head)
    c, s = math.cos(0.7), math.sin(0.7)
    yaw = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    np.testing.assert_allclose(pos, np.array([0.5, -0.3, 0.0]) + yaw @ bpos, atol=1e-4)
    np.testing.assert_allclose(rot, yaw @ brot, atol=1e-4)


def _trap(world: World) -> None:
    for _ in range(24):
        world.step(_cmd(ind="trap"))
    for _ in range(3):
        world.step(_cmd())


def test_trap_captures_and_holds_the_ball_while_walking_and_turning(world: World) -> None:
    _reset(world, (0.0, 0.0, 0.0), (0.24, 0.02))
    _trap(world)
    assert world.holding and world.counters["traps_ok"] == 1
    for y in [_cmd(turn=1.5)] * 45 + [_cmd(fwd=0.2, left=0.05)] * 45:
        world.step(y)
        bx, by, bz = world.ball_in_robot_frame()
        assert bx == pytest.approx(CFG.motion.hold_x, abs=0.01)
        assert abs(by) < 0.01 and bz == pytest.approx(CFG.ball.radius, abs=0.005)
    assert world.holding


def test_trap_misses_a_ball_out_of_reach(world: World) -> None:
    _reset(world, (0.0, 0.0, 0.0), (0.6, 0.0))
    _trap(world)
    assert not world.holding and world.counters["traps"] == 1
    assert world.counters["traps_ok"] == 0


def test_a_held_ball_is_dropped_after_the_hold_timeout(world: World) -> None:
    _reset(world, (0.0, 0.0, 0.0), (0.22, 0.0))
    _trap(world)
    assert world.holding
    for _ in range(int(CFG.motion.hold_timeout / DT)):
        world.step(_cmd())
    assert not world.holding and world.counters["drops"] == 1


def test_kick_distance_and_heading_match_the_calibration() -> None:
    """60 kicks from a trap: [UTK] mean 2.15 m, ~1/3 short of 2 m, longest 4.05 m; ~10 deg."""
    w = World(CFG)
    dist, head = [], []
    try:
        for i in range(60):
            w.reset(
                (-2.3, 0.0, 0.0),
                (-2.08, 0.0),
                np.random.default_rng(i),
                np.random.default_rng(1000 + i),
            )
            _trap(w)
            assert w.holding
            start = np.array(w.ball_position()[:2])
            for _ in range(24):
                w.step(_cmd(ind="kick"))
            for _ in range(300):
                w.step(_cmd())
                if np.hypot(*w.ball_velocity()[:2]) < 0.01:
                    break
            d = np.array(w.ball_position()[:2]) - start
            dist.append(float(np.hypot(*d)))
            head.append(math.degrees(math.atan2(d[1], d[0])))
    finally:
        w.close()
    dist_a, head_a = np.array(dist), np.array(head)
    assert 1.9 <= dist_a.mean() <= 2.4
    assert 0.15 <= float(np.mean(dist_a < 2.0)) <= 0.6
    assert dist_a.max() <= 4.15 and dist_a.min() >= 0.4
    assert 6.0 <= head_a.std() <= 14.0 and abs(head_a.mean()) < 4.0


def test_same_seed_same_trajectory_and_different_seed_differs() -> None:
    from simulator.controllers.hcc import HCC

    def trajectory(seed: int) -> np.ndarray:
        sim = SoccerSim(vision="rendered")
        hcc = HCC()
        x = sim.reset(4, seed)
        hcc.reset()
        rows = []
        for _ in range(150):
            y, _ = hcc.act(x)
            t = sim.truth()
            rows.append(
                [*x, *y, t["robot_x"], t["robot_y"], t["robot_yaw"], t["ball_x"], t["ball_y"]]
            )
            if sim.step(y):
                break
            x = sim.perceive()
        sim.close()
        return np.array(rows)

    a, b, c = trajectory(5), trajectory(5), trajectory(6)
    np.testing.assert_array_equal(a, b)
    assert a.shape != c.shape or not np.array_equal(a, c)


def _sim_with_ball(xy: tuple[float, float], v: tuple[float, float], limit: float = 150.0):
    cfg = replace(CFG, episode=replace(CFG.episode, time_limit=limit))
    sim = SoccerSim(cfg, vision="fast")
    sim.reset(6, 0)
    import pybullet as p

    w = sim.world
    p.resetBasePositionAndOrientation(w.ball, (*xy, 0.042), (0, 0, 0, 1), physicsClientId=w.client)
    p.resetBaseVelocity(w.ball, (*v, 0), (-v[1] / 0.042, v[0] / 0.042, 0), physicsClientId=w.client)
    return sim


@pytest.mark.parametrize(
    ("xy", "v", "outcome"),
    [
        ((2.5, 0.0), (1.5, 0.0), "goal"),
        ((-2.5, 0.1), (-1.5, 0.0), "own_goal"),
        ((2.5, 0.8), (1.5, 0.0), "out"),
        ((0.0, 1.6), (0.0, 1.5), "out"),
        ((0.0, 0.0), (0.0, 0.0), "timeout"),
    ],
)
def test_episode_outcomes(xy, v, outcome) -> None:
    sim = _sim_with_ball(xy, v, limit=2.0)
    try:
        got = None
        for _ in range(200):
            got = sim.step(np.zeros(9))
            if got:
                break
        assert got == outcome
        res = sim.result()
        assert res.success == (outcome == "goal")
        if outcome == "timeout":
            assert res.sim_time_s == pytest.approx(2.0, abs=DT)
    finally:
        sim.close()


def test_start_locations_are_13_inside_the_field_and_parse() -> None:
    assert len(START_LOCATIONS) == 13
    f = CFG.field
    for loc in START_LOCATIONS:
        for x, y in (loc.robot[:2], loc.ball):
            assert abs(x) < f.length / 2 - 0.3 and abs(y) < f.width / 2 - 0.3
    xs = [loc.robot[0] for loc in START_LOCATIONS]
    assert min(xs) <= -1.5 and max(xs) >= 1.5  # spread over both halves
    assert parse_locations("all") == list(range(13))
    assert parse_locations("0,3-5,12") == [0, 3, 4, 5, 12]
    with pytest.raises(ValueError):
        parse_locations("13")


def test_config_file_overrides_and_rejects_unknown_keys(tmp_path) -> None:
    p = tmp_path / "t.toml"
    p.write_text('[sim]\nvision = "fast"\n[sim.camera]\nwidth = 104\nheight = 80\n')
    cfg = load_config(p)
    assert cfg.vision == "fast" and cfg.camera.width == 104
    assert cfg.camera.vfov == pytest.approx(CFG.camera.vfov, abs=0.01)
    p.write_text("[sim.camera]\nwidht = 104\n")
    with pytest.raises(SimConfigError, match="widht"):
        load_config(p)
    p.write_text("[sim.walk]\nmax_turn = -1.0\n")
    with pytest.raises(SimConfigError, match="max_turn"):
        load_config(p)
    assert load_config("configs/aibo.toml") == CFG


def test_episode_result_measures_the_robots_and_the_balls_path() -> None:
    """``path_m`` is the robot's walked distance (the 'stands still' failure mode on both
    paths), ``ball_path_m`` the ball's: standing gives ~0, walking 2 s at a command below the
    limit gives speed x time within the ramp and the 5 % execution noise."""
    sim = SoccerSim(replace(CFG, episode=replace(CFG.episode, time_limit=10.0)))
    try:
        sim.reset(0, seed=1)
        for _ in range(30):
            sim.step(_cmd())
        still = sim.result()
        assert still.path_m < 0.01 and still.to_map()["path_m"] == round(still.path_m, 3)
        sim.reset(4, seed=1)
        v = 0.5 * CFG.walk.max_forward
        for _ in range(60):
            sim.step(_cmd(fwd=v))
        walked = sim.result()
        # acceleration accel_factor x max_forward per second: v is reached after this long
        ramp = v / (CFG.walk.accel_factor * CFG.walk.max_forward)
        assert walked.path_m == pytest.approx(v * (2.0 - ramp / 2), rel=0.06)
        assert walked.ball_path_m >= 0.0 and "ball_path_m" in walked.to_map()
    finally:
        sim.close()
