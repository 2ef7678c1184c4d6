"""Colour-blob vision: rendered segmentation and the fast analytic path, and their agreement."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import brentq

from protocols.aibo import COLOURS, NOT_SEEN
from simulator.config import CameraConfig, SimConfig
from simulator.controllers.hcc import HeadModel
from simulator.vision import FastVision, RenderedVision, apply_noise
from simulator.world import World

BALL, YELLOW, BLUE = (COLOURS.index(c) for c in ("ball", "yellow_goal", "blue_goal"))


@pytest.fixture(scope="module")
def world() -> World:
    w = World(SimConfig())
    yield w
    w.close()


def _place(w: World, pose: tuple[float, float, float], ball: tuple[float, float]) -> None:
    w.reset(pose, ball, np.random.default_rng(0), np.random.default_rng(1))


def _both(w: World) -> tuple[np.ndarray, np.ndarray]:
    cam = w.cfg.camera
    return RenderedVision(w, cam).blobs(), FastVision(w, cam).blobs()


def test_ball_straight_ahead_is_a_centred_orange_blob(world: World) -> None:
    _place(world, (0.0, 0.0, 0.0), (0.6, 0.0))
    eye, _ = world.camera_pose()
    dist = math.dist(eye, (0.6, 0.0, 0.042))
    for blobs in _both(world):
        x, y, size = blobs[BALL]
        assert abs(x) < 0.03  # horizontally centred
        assert -0.3 < y < -0.1  # below the centre: the head looks 15 deg down, the ball is lower
        # size = sqrt(pi) f r / (d sqrt(W H)) for a disc of radius f r / d pixels
        expected = math.sqrt(math.pi) * 192.0 * 0.042 / (dist * math.sqrt(208 * 160))
        assert size == pytest.approx(expected, rel=0.12)


def test_ball_on_the_left_has_negative_x_and_head_pan_brings_it_back(world: World) -> None:
    _place(world, (0.0, 0.0, 0.0), (0.8, 0.25))
    rv = RenderedVision(world, world.cfg.camera)
    assert rv.blobs()[BALL, 0] < -0.3
    # the pan that puts the ball on the optical plane, from the controller's own head model
    head = HeadModel()
    ball = np.array([0.8, 0.25, 0.042])

    def left_of_axis(pan: float) -> float:
        pos, rot = head.camera_pose(world.head[0], pan, world.head[2])
        return float((ball - pos) @ rot[:, 1])

    pan = brentq(left_of_axis, 0.0, 1.2)
    world.head[1] = pan
    world._apply_joints()
    assert abs(rv.blobs()[BALL, 0]) < 0.03


def test_objects_behind_the_robot_are_not_seen(world: World) -> None:
    # robot in front of the blue goal facing the yellow one; ball behind the robot
    _place(world, (2.0, 0.0, math.pi), (2.5, 0.0))
    for blobs in _both(world):
        assert tuple(blobs[BALL]) == NOT_SEEN
        assert tuple(blobs[BLUE]) == NOT_SEEN
        assert blobs[YELLOW, 2] > 0  # the goal ahead, 4.7 m away, is seen


def test_ball_hidden_behind_a_goal_wall_is_not_seen(world: World) -> None:
    # looking at the outside of the blue goal's left wall; the ball sits inside the goal
    _place(world, (2.85, 0.9, -math.pi / 2), (2.85, 0.2))
    for blobs in _both(world):
        assert blobs[BLUE, 2] > 0.2
        assert tuple(blobs[BALL]) == NOT_SEEN


def test_held_ball_under_the_chin_is_out_of_view(world: World) -> None:
    _place(world, (0.0, 0.0, 0.0), (world.cfg.motion.hold_x, 0.0))
    for blobs in _both(world):
        assert tuple(blobs[BALL]) == NOT_SEEN


def test_resolution_does_not_change_the_encoding(world: World) -> None:
    _place(world, (-0.5, 0.3, 0.3), (0.4, 0.5))
    full = RenderedVision(world, world.cfg.camera).blobs()
    half = RenderedVision(world, CameraConfig(width=104, height=80)).blobs()
    seen = full[:, 2] > 0.05
    assert seen.any()
    np.testing.assert_allclose(half[seen, :2], full[seen, :2], atol=0.03)
    np.testing.assert_allclose(half[seen, 2], full[seen, 2], rtol=0.15)


def test_fast_vision_agrees_with_rendered_over_random_views(world: World) -> None:
    """Cross-check: 40 random robot poses and ball positions over the whole field."""
    rng = np.random.default_rng(7)
    cam = world.cfg.camera
    agree = disagree = 0
    dxy: list[float] = []
    rel: list[float] = []
    for _ in range(40):
        pose = (rng.uniform(-2.5, 2.5), rng.uniform(-1.6, 1.6), rng.uniform(-math.pi, math.pi))
        ang = pose[2] + rng.uniform(-0.6, 0.6)
        d = rng.uniform(0.3, 2.0)
        ball = (
            float(np.clip(pose[0] + d * math.cos(ang), -2.6, 2.6)),
            float(np.clip(pose[1] + d * math.sin(ang), -1.7, 1.7)),
        )
        _place(world, pose, ball)
        world.head = np.array([rng.uniform(-0.6, 0.0), rng.uniform(-0.8, 0.8), 0.0])
        world._apply_joints()
        r = RenderedVision(world, cam).blobs()
        f = FastVision(world, cam).blobs()
        for k in range(len(COLOURS)):
            big = r[k, 2] >= 0.06 and abs(r[k, 0]) < 0.85 and abs(r[k, 1]) < 0.6
            if not big:
                continue  # tiny or edge-clipped blobs: the patch model is too coarse there
            if f[k, 2] > 0:
                agree += 1
                dxy.append(max(abs(f[k, 0] - r[k, 0]), abs(f[k, 1] - r[k, 1])))
                rel.append(abs(f[k, 2] - r[k, 2]) / r[k, 2])
            else:
                disagree += 1
    assert agree >= 30
    assert disagree <= 0.05 * (agree + disagree)
    assert float(np.median(dxy)) < 0.02
    assert float(np.percentile(dxy, 90)) < 0.08
    assert float(np.median(rel)) < 0.1
    assert float(np.percentile(rel, 90)) < 0.3


def test_noise_is_seeded_and_keeps_not_seen() -> None:
    blobs = np.array([NOT_SEEN] * 6, dtype=float)
    blobs[0] = (0.1, -0.2, 0.3)
    noise = replace(SimConfig().noise, dropout=0.0)
    a = apply_noise(blobs, np.random.default_rng(3), noise)
    b = apply_noise(blobs, np.random.default_rng(3), noise)
    np.testing.assert_array_equal(a, b)
    assert tuple(a[1]) == NOT_SEEN
    assert a[0, 0] != 0.1 and abs(a[0, 0] - 0.1) < 0.05
    dropped = apply_noise(blobs, np.random.default_rng(3), replace(noise, dropout=0.999999))
    assert tuple(dropped[0]) == NOT_SEEN
