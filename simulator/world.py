"""The pybullet world: field, goals, beacons, ball and an ERS-7-like robot, all primitives.

Frame: metres, +x from the own goal towards the opponent goal, +z up, the field centre at the
origin. The robot's body frame has +x forward, +y left. Heading 0 faces the opponent goal.

The scene is built by :mod:`simulator.field`. The robot is a dynamic body (trunk and four
legs) carried by a force-limited fixed constraint whose target the walk engine moves
(docs/aibo-simulation.md §4.2): it pushes the ball and is stopped by walls and posts. Head
(tilt, pan, nod) and tail (pan, tilt) are real revolute links, set kinematically (rate-limited
to Sony's maximum joint speeds) and carrying the camera link. Trap and kick are scripted
time-extended motions (docs/aibo-simulation.md §4.3): a trapped ball is held under the chin
until it is kicked (impulse with Gaussian heading noise) or dropped on timeout.

One :class:`World` owns one DIRECT pybullet client. :meth:`World.reset` rebuilds the scene
from scratch (``resetSimulation``), so an episode depends only on its seed and commands.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from protocols.aibo import decode_indicator
from simulator.bullet import p
from simulator.config import SimConfig
from simulator.field import (
    CAMERA_LINK,
    HEAD_JOINTS,
    TAIL_JOINTS,
    Instance,
    build_scene,
    quat_yaw,
)

__all__ = [
    "CAMERA_LINK",
    "HEAD_JOINTS",
    "TAIL_JOINTS",
    "Instance",
    "MotionState",
    "World",
    "yaw_of",
]

_MAX_LAG = 0.02  # m the walk target may lead the body
_MAX_YAW_LAG = 0.1  # rad

def yaw_of(quat: tuple[float, ...] | list[float]) -> float:
    """Yaw (rotation about +z) of a quaternion (x, y, z, w)."""
    x, y, z, w = quat
    return math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


@dataclass
class MotionState:
    """A running time-extended motion: ``kind`` is ``"trap"`` or ``"kick"``."""

    kind: str
    start_tick: int
    done_event: bool = False  # capture attempted / ball released


class World:
    """The simulated field and robot; see the module docstring for frames and modelling."""

    def __init__(self, cfg: SimConfig) -> None:
        self.cfg = cfg
        self.client = p.connect(p.DIRECT)
        self.instances: list[Instance] = []
        self.robot = -1
        self.ball = -1
        self._cid = -1
        self.tick = 0
        self.v = np.zeros(3)  # executed walk velocity (forward, left, turn), after accel limits
        self.head = np.zeros(3)  # tilt, pan, nod (rad)
        self.tail = np.zeros(2)  # pan, tilt (rad)
        self.motion: MotionState | None = None
        self.holding = False
        self.hold_since = 0
        self.counters: dict[str, int] = {}
        self._rng = np.random.default_rng(0)
        self._kick_rng = np.random.default_rng(0)

    # --- construction --------------------------------------------------------------------

    def close(self) -> None:
        """Disconnect the pybullet client."""
        if self.client >= 0:
            p.disconnect(physicsClientId=self.client)
            self.client = -1

    def reset(
        self,
        robot_pose: tuple[float, float, float],
        ball_xy: tuple[float, float],
        rng: np.random.Generator,
        kick_rng: np.random.Generator,
    ) -> None:
        """Rebuild the scene; robot at (x, y, heading rad), ball resting at ``ball_xy``.

        ``rng`` draws the walk noise, ``kick_rng`` the kick outcomes.
        """
        c = self.client
        p.resetSimulation(physicsClientId=c)
        dt = self.cfg.episode.dt / self.cfg.episode.substeps
        p.setPhysicsEngineParameter(
            fixedTimeStep=dt, numSubSteps=0, deterministicOverlappingPairs=1, physicsClientId=c
        )
        p.setGravity(0, 0, -9.81, physicsClientId=c)
        scene = build_scene(c, self.cfg, robot_pose, ball_xy)
        self.instances = scene.instances
        self.ground, self.ball, self.robot, self._cid = (
            scene.ground, scene.ball, scene.robot, scene.constraint)
        self._target = [float(robot_pose[0]), float(robot_pose[1]), float(robot_pose[2])]
        self.tick = 0
        self.v = np.zeros(3)
        r = self.cfg.robot
        self.head = np.radians([-15.0, 0.0, 0.0])
        self.tail = np.radians([0.0, r.tail_tilt_range[0] + 10.0])
        self._apply_joints()
        self.motion = None
        self.holding = False
        self.hold_since = 0
        self.counters = {"traps": 0, "traps_ok": 0, "kicks": 0, "kicks_ball": 0, "drops": 0}
        self._rng = rng
        self._kick_rng = kick_rng

    # --- state ---------------------------------------------------------------------------

    def robot_pose(self) -> tuple[float, float, float]:
        """(x, y, heading rad) of the trunk centre."""
        pos, orn = p.getBasePositionAndOrientation(self.robot, physicsClientId=self.client)
        return float(pos[0]), float(pos[1]), yaw_of(orn)

    def ball_position(self) -> tuple[float, float, float]:
        """World position of the ball centre."""
        pos, _ = p.getBasePositionAndOrientation(self.ball, physicsClientId=self.client)
        return float(pos[0]), float(pos[1]), float(pos[2])

    def ball_velocity(self) -> tuple[float, float, float]:
        """World linear velocity of the ball."""
        lin, _ = p.getBaseVelocity(self.ball, physicsClientId=self.client)
        return float(lin[0]), float(lin[1]), float(lin[2])

    def ball_in_robot_frame(self) -> tuple[float, float, float]:
        """Ball centre in the robot's body frame (x forward, y left, z up from the floor)."""
        x, y, yaw = self.robot_pose()
        bx, by, bz = self.ball_position()
        dx, dy = bx - x, by - y
        cs, sn = math.cos(yaw), math.sin(yaw)
        return cs * dx + sn * dy, -sn * dx + cs * dy, bz

    def camera_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Camera position and rotation matrix (columns: forward, left, up) in the world."""
        st = p.getLinkState(
            self.robot, CAMERA_LINK, computeForwardKinematics=1, physicsClientId=self.client
        )
        pos = np.array(st[4], dtype=np.float64)
        rot = np.array(p.getMatrixFromQuaternion(st[5]), dtype=np.float64).reshape(3, 3)
        return pos, rot

    def joint_angles(self) -> np.ndarray:
        """Measured head (tilt, pan, nod) and tail (pan, tilt) angles in radians."""
        states = p.getJointStates(
            self.robot, [*HEAD_JOINTS, *TAIL_JOINTS], physicsClientId=self.client
        )
        return np.array([s[0] for s in states], dtype=np.float64)

    # --- actuation -----------------------------------------------------------------------

    def _limits(self) -> tuple[np.ndarray, np.ndarray]:
        r = self.cfg.robot
        lo = np.radians(
            [
                r.tilt_range[0],
                r.pan_range[0],
                r.nod_range[0],
                r.tail_pan_range[0],
                r.tail_tilt_range[0],
            ]
        )
        hi = np.radians(
            [
                r.tilt_range[1],
                r.pan_range[1],
                r.nod_range[1],
                r.tail_pan_range[1],
                r.tail_tilt_range[1],
            ]
        )
        return lo, hi

    def _apply_joints(self) -> None:
        c = self.client
        for j, a in zip((*HEAD_JOINTS, *TAIL_JOINTS), (*self.head, *self.tail), strict=True):
            p.resetJointState(self.robot, j, float(a), 0.0, physicsClientId=c)

    def _move_joints(self, head_target: np.ndarray, tail_target: np.ndarray) -> None:
        r = self.cfg.robot
        dt = self.cfg.episode.dt
        lo, hi = self._limits()
        target = np.clip(np.concatenate([head_target, tail_target]), lo, hi)
        current = np.concatenate([self.head, self.tail])
        speed = np.array([r.tilt_speed, r.pan_speed, r.nod_speed, r.tail_speed, r.tail_speed])
        step = np.clip(target - current, -speed * dt, speed * dt)
        new = np.clip(current + step, lo, hi)
        self.head, self.tail = new[:3], new[3:]
        self._apply_joints()

    def clip_walk(self, cmd: np.ndarray) -> np.ndarray:
        """Clip a (forward, left, turn) command to the walk engine's velocity limits."""
        w = self.cfg.walk
        return np.array(
            [
                np.clip(cmd[0], -w.max_backward, w.max_forward),
                np.clip(cmd[1], -w.max_side, w.max_side),
                np.clip(cmd[2], -w.max_turn, w.max_turn),
            ]
        )

    def step(self, y: np.ndarray) -> None:
        """Execute one control tick of the 9-D command ``y`` (see ``protocols/AIBO.md``)."""
        y = np.asarray(y, dtype=np.float64)
        cfg = self.cfg
        dt = cfg.episode.dt
        indicator = decode_indicator(float(y[8]))
        if self.motion is None and indicator in ("trap", "kick"):
            self.motion = MotionState(indicator, self.tick)
            self.counters["traps" if indicator == "trap" else "kicks"] += 1
        walk_cmd = self.clip_walk(y[0:3])
        head_target = np.array(y[3:6], dtype=np.float64)
        if self.motion is not None:
            walk_cmd, head_target = self._motion_overrides(head_target)
        self._move_joints(head_target, np.array(y[6:8], dtype=np.float64))
        # Acceleration limits, then seeded execution noise.
        w = cfg.walk
        lim = np.array([w.max_forward, w.max_side, w.max_turn])
        dv = np.clip(walk_cmd - self.v, -w.accel_factor * lim * dt, w.accel_factor * lim * dt)
        self.v = self.v + dv
        executed = self.v * (1.0 + w.noise * self._rng.standard_normal(3))
        self._substeps(executed)
        self.tick += 1
        self._motion_events()

    def _motion_overrides(self, head_target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        m = self.motion
        assert m is not None
        mc = self.cfg.motion
        t = (self.tick - m.start_tick) * self.cfg.episode.dt
        if m.kind == "trap":
            speed = mc.trap_lunge_speed if t < mc.trap_lunge_time else 0.0
            return np.array([speed, 0.0, 0.0]), np.radians([-60.0, 0.0, -10.0])
        return np.zeros(3), head_target  # kick: stand still, head as commanded

    def _motion_events(self) -> None:
        mc = self.cfg.motion
        dt = self.cfg.episode.dt
        m = self.motion
        if m is not None:
            t = (self.tick - m.start_tick) * dt
            if m.kind == "trap" and not m.done_event and t >= mc.trap_capture_time:
                m.done_event = True
                if not self.holding and self._ball_in_capture_box():
                    self.holding = True
                    self.hold_since = self.tick
                    self.counters["traps_ok"] += 1
            if m.kind == "kick" and not m.done_event and t >= mc.kick_release_time:
                m.done_event = True
                if self.holding or self._ball_in_capture_box():
                    self._launch()
            duration = mc.trap_time if m.kind == "trap" else mc.kick_time
            if t >= duration - 1e-9:
                self.motion = None
        if self.holding and (self.tick - self.hold_since) * dt >= mc.hold_timeout:
            self.holding = False
            self.counters["drops"] += 1

    def _ball_in_capture_box(self) -> bool:
        mc = self.cfg.motion
        bx, by, bz = self.ball_in_robot_frame()
        return (
            mc.capture_x[0] <= bx <= mc.capture_x[1]
            and abs(by) <= mc.capture_y
            and bz <= 2.5 * self.cfg.ball.radius
        )

    def _chin_world(self) -> tuple[float, float, float]:
        x, y, yaw = self.robot_pose()
        hx = self.cfg.motion.hold_x
        return x + hx * math.cos(yaw), y + hx * math.sin(yaw), self.cfg.ball.radius

    def _launch(self) -> None:
        mc = self.cfg.motion
        rng = self._kick_rng
        _, _, yaw = self.robot_pose()
        heading = yaw + math.radians(mc.kick_heading_sd) * float(rng.standard_normal())
        lo, hi = mc.kick_distance_range
        dist = float(
            np.clip(mc.kick_distance_mean + mc.kick_distance_sd * rng.standard_normal(), lo, hi)
        )
        speed = math.sqrt(dist / mc.kick_distance_per_speed2)
        vx, vy = speed * math.cos(heading), speed * math.sin(heading)
        r = self.cfg.ball.radius
        c = self.client
        p.resetBasePositionAndOrientation(
            self.ball, self._chin_world(), (0, 0, 0, 1), physicsClientId=c
        )
        p.resetBaseVelocity(self.ball, (vx, vy, 0.0), (-vy / r, vx / r, 0.0), physicsClientId=c)
        self.holding = False
        self.counters["kicks_ball"] += 1

    def _substeps(self, v_body: np.ndarray) -> None:
        c = self.client
        n = self.cfg.episode.substeps
        h = self.cfg.episode.dt / n
        # Integrate the constraint target, not the measured pose (no steady-state lag); if the
        # body is blocked, keep the target within MAX_LAG of it (no wind-up).
        ax, ay, ayaw = self.robot_pose()
        x, y, yaw = self._target
        ex, ey = x - ax, y - ay
        lag = math.hypot(ex, ey)
        if lag > _MAX_LAG:
            x, y = ax + ex * _MAX_LAG / lag, ay + ey * _MAX_LAG / lag
        eyaw = math.remainder(yaw - ayaw, math.tau)
        if abs(eyaw) > _MAX_YAW_LAG:
            yaw = ayaw + math.copysign(_MAX_YAW_LAG, eyaw)
        z = self.cfg.robot.trunk_height
        for _ in range(n):
            yaw += v_body[2] * h
            cs, sn = math.cos(yaw), math.sin(yaw)
            x += (cs * v_body[0] - sn * v_body[1]) * h
            y += (sn * v_body[0] + cs * v_body[1]) * h
            p.changeConstraint(
                self._cid,
                (x, y, z),
                quat_yaw(yaw),
                maxForce=self.cfg.walk.max_force,
                physicsClientId=c,
            )
            if self.holding:
                self._carry_ball(v_body)
            p.stepSimulation(physicsClientId=c)
        self._target = [x, y, yaw]

    def _carry_ball(self, v_body: np.ndarray) -> None:
        c = self.client
        x, y, yaw = self.robot_pose()
        cs, sn = math.cos(yaw), math.sin(yaw)
        hx = self.cfg.motion.hold_x
        p.resetBasePositionAndOrientation(
            self.ball, self._chin_world(), (0, 0, 0, 1), physicsClientId=c
        )
        vx = cs * v_body[0] - sn * v_body[1] - v_body[2] * hx * sn
        vy = sn * v_body[0] + cs * v_body[1] + v_body[2] * hx * cs
        p.resetBaseVelocity(self.ball, (vx, vy, 0.0), (0.0, 0.0, 0.0), physicsClientId=c)
