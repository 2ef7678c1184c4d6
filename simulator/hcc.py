"""The hand-coded controller (HCC): a seek / trap / aim / kick finite-state machine.

It acts only on the 23-D perception (``protocols/AIBO.md``) plus its own state and timers,
like the paper's controller on the real robot (section IV, Fig. 6a). It knows its own body
(head kinematics, camera model, motion durations), but never sees the world's ground truth.

Subtasks (labels reported with every action):

* ``seek``: the ball is not seen. Turn in place towards where the ball was last seen, panning
  the head; after a full turn without the ball, walk forward for a while and turn again.
* ``trap``: walk to the ball (head tracks it, body turns to it, slows down when close), and
  when the ball is under the chin trigger the trap motion (action indicator = trap for the
  motion's length). The ball lost for ``ball_lost_time`` -> seek. Motion done -> aim.
* ``aim``: the ball is held under the chin, out of view; the head looks ahead in the *look
  pose*. Turn towards the opponent goal (its remembered bearing when not in view) until it is
  centred, then kick. A ball seen in front means the trap failed -> trap. Timeout -> kick.
* ``kick``: the kick motion (action indicator = kick for its length), then seek.

Perceptual aliasing (the paper's multimap): while aiming the robot cannot see the ball and the
goal at once, and its head pose (the look pose) is also passed through by the seek head scan,
so the same perception is met in seek (turn to find the ball), aim (turn to the goal) and kick
(stand and kick). The tail wags on a clock that ignores the FSM state, so it leaks nothing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from protocols.aibo import COLOURS, DIMS, SUBTASKS, blob_slice, encode_indicator
from simulator.config import CameraConfig, MotionConfig, RobotConfig

__all__ = ["HCC", "HCCParams", "HeadModel"]


@dataclass(frozen=True)
class HCCParams:
    """Thresholds, gains and timers of the FSM (seconds, metres, radians unless noted)."""

    hz: float = 30.0
    attack: str = "blue"  # opponent goal colour
    ball_radius: float = 0.042
    # look pose: aim and kick hold it; the seek scan passes through it
    look_tilt: float = math.radians(-15.0)
    look_nod: float = 0.0
    # seek
    see_ticks: int = 2
    seek_turn: float = 1.5
    seek_pan_amp: float = math.radians(60.0)
    seek_pan_period: float = 2.0
    wander_time: float = 2.5
    wander_speed: float = 0.2
    # trap (approach + motion)
    ball_lost_time: float = 0.6
    approach_turn_gain: float = 2.5
    approach_speed: float = 0.22
    approach_slow_dist: float = 0.45
    approach_slow_speed: float = 0.09
    approach_side_gain: float = 1.5
    trap_forward: tuple[float, float] = (0.17, 0.27)  # ball x in the body frame to trigger
    trap_left: float = 0.035
    head_track_gain: float = 0.6
    # aim
    aim_turn: float = 1.5
    aim_turn_gain: float = 2.5
    aim_tolerance: float = math.radians(5.0)
    aim_settle_ticks: int = 3
    aim_timeout: float = 5.0
    # tail: state-independent wag
    tail_pan_amp: float = math.radians(20.0)
    tail_period: float = 2.0
    tail_tilt: float = math.radians(20.0)

    def __post_init__(self) -> None:
        if self.attack not in ("blue", "yellow"):
            raise ValueError(f"HCCParams.attack must be 'blue' or 'yellow', got {self.attack!r}")
        for name in ("hz", "seek_turn", "aim_turn", "aim_timeout", "approach_speed"):
            if not getattr(self, name) > 0:
                raise ValueError(f"HCCParams.{name} must be > 0")


def _rot_pitch(a: float) -> np.ndarray:
    """Rotation about -y by ``a`` (positive pitches +x up)."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])


def _rot_yaw(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class HeadModel:
    """The robot's own head kinematics and camera model (what the controller may know)."""

    robot: RobotConfig = field(default_factory=RobotConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)

    @property
    def fn(self) -> float:
        """Focal length normalised by the half image width."""
        return 1.0 / math.tan(math.radians(self.camera.hfov) / 2)

    def camera_pose(self, tilt: float, pan: float, nod: float) -> tuple[np.ndarray, np.ndarray]:
        """Camera position (body frame, z from the floor) and rotation (columns fwd, left, up)."""
        r = self.robot
        r_tilt = _rot_pitch(tilt)
        r_head = r_tilt @ _rot_yaw(pan) @ _rot_pitch(nod)
        base = np.array([r.neck_base[0], 0.0, r.trunk_height + r.neck_base[1]])
        off = np.array([r.camera_offset[0], 0.0, r.camera_offset[1]])
        pos = base + r_tilt @ np.array([0.0, 0.0, r.neck_length]) + r_head @ off
        return pos, r_head

    def ray(self, bx: float, by: float, rot: np.ndarray) -> np.ndarray:
        """Unit direction (body frame) through image point (bx, by) of the encoding."""
        d = rot @ np.array([1.0, -bx / self.fn, by / self.fn])
        return d / np.linalg.norm(d)

    def bearing(self, bx: float, by: float, tilt: float, pan: float, nod: float) -> float:
        """Bearing (rad, positive left) of an image point in the body frame."""
        _, rot = self.camera_pose(tilt, pan, nod)
        d = self.ray(bx, by, rot)
        return math.atan2(d[1], d[0])

    def ball_position(
        self,
        bx: float,
        by: float,
        size: float,
        tilt: float,
        pan: float,
        nod: float,
        radius: float,
    ) -> tuple[float, float]:
        """Ball centre (forward, left) in the body frame from its blob and the head angles.

        Intersects the viewing ray with the plane z = radius when it points clearly down;
        otherwise uses the apparent size (size = sqrt(pi) f r / (d sqrt(W H))).
        """
        pos, rot = self.camera_pose(tilt, pan, nod)
        d = self.ray(bx, by, rot)
        if d[2] < -0.12:
            s = (radius - pos[2]) / d[2]
        else:
            cam = self.camera
            f_px = cam.focal_px
            s = (
                math.sqrt(math.pi)
                * f_px
                * radius
                / (max(size, 1e-3) * math.sqrt(cam.width * cam.height))
            )
        q = pos + s * d
        return float(q[0]), float(q[1])


class HCC:
    """The FSM. ``act(x)`` -> (9-D action, subtask label); ``reset()`` between episodes.

    For the transitioner, :meth:`decide` computes the FSM's own action without committing it,
    and :meth:`commit` tells the FSM which command was actually executed (it integrates its
    own turn commands to remember where the ball and the goal were).
    """

    def __init__(
        self,
        params: HCCParams | None = None,
        head: HeadModel | None = None,
        motion: MotionConfig | None = None,
    ) -> None:
        self.p = params or HCCParams()
        self.head = head or HeadModel()
        self.motion = motion or MotionConfig()
        self._goal = blob_slice(f"{self.p.attack}_goal")
        own = "yellow" if self.p.attack == "blue" else "blue"
        self._own = blob_slice(f"{own}_goal")
        self._ball = blob_slice("ball")
        self.transitions: list[tuple[int, str, str]] = []
        self.reset()

    # --- state -------------------------------------------------------------------------

    def reset(self) -> None:
        """Back to seek, clear memories and timers."""
        self.state = "seek"
        self.tick = 0
        self.state_ticks = 0
        self.seen_ticks = 0
        self.unseen_ticks = 0
        self.ball_bearing = 0.0  # remembered bearing of the ball (rad, body frame)
        self.ball_memory = False
        self.goal_bearing = 0.0  # remembered bearing of the opponent goal
        self.goal_memory = False
        self.turned = 0.0  # |turn| accumulated in the current seek sweep
        self.wander_ticks = 0
        self.motion_ticks = -1  # ticks into the trap/kick motion, -1 when none
        self.settle = 0
        self.transitions = []

    def _go(self, state: str) -> None:
        if state != self.state:
            self.transitions.append((self.tick, self.state, state))
            self.state = state
            self.state_ticks = 0
            self.motion_ticks = -1
            self.settle = 0
            self.turned = 0.0
            self.wander_ticks = 0

    # --- the controller ------------------------------------------------------------------

    def act(self, x: np.ndarray) -> tuple[np.ndarray, str]:
        """Decide on perception ``x`` and commit the decision; returns (action, subtask)."""
        y, label = self.decide(x)
        self.commit(y)
        return y, label

    def decide(self, x: np.ndarray) -> tuple[np.ndarray, str]:
        """Run the FSM one tick on ``x``; returns its action and the subtask that produced it."""
        x = np.asarray(x, dtype=np.float64)
        if x.shape != (DIMS.x,):
            raise ValueError(f"perception must have {DIMS.x} entries, got {x.shape}")
        p = self.p
        dt = 1.0 / p.hz
        tilt, pan, nod = (float(v) for v in x[18:21])
        ball = x[self._ball]
        goal = x[self._goal]
        own = x[self._own]
        ball_seen = ball[2] > 0
        self.seen_ticks = self.seen_ticks + 1 if ball_seen else 0
        self.unseen_ticks = 0 if ball_seen else self.unseen_ticks + 1
        if ball_seen:
            self.ball_bearing = self.head.bearing(ball[0], ball[1], tilt, pan, nod)
            self.ball_memory = True
        if goal[2] > 0:
            self.goal_bearing = self.head.bearing(goal[0], goal[1], tilt, pan, nod)
            self.goal_memory = True
        elif own[2] > 0:
            own_b = self.head.bearing(own[0], own[1], tilt, pan, nod)
            self.goal_bearing = math.remainder(own_b + math.pi, math.tau)
            self.goal_memory = True

        # transitions
        if self.state == "seek" and self.seen_ticks >= p.see_ticks:
            self._go("trap")
        elif self.state == "trap" and self.motion_ticks < 0:
            if self.unseen_ticks * dt >= p.ball_lost_time:
                self._go("seek")
        elif self.state == "aim" and ball_seen and self.state_ticks > 0.5 * p.hz:
            self._go("trap")  # the ball is in front of us: the trap failed

        y = np.zeros(DIMS.y)
        y[3:6] = (p.look_tilt, 0.0, p.look_nod)
        handler = {"seek": self._seek, "trap": self._trap, "aim": self._aim, "kick": self._kick}
        handler[self.state](y, x, dt)
        # tail: wag on the controller's clock, identical in every state
        phase = 2 * math.pi * self.tick * dt / p.tail_period
        y[6] = p.tail_pan_amp * math.sin(phase)
        y[7] = p.tail_tilt
        label = self._label
        return y, label

    def commit(self, y: np.ndarray) -> None:
        """Account for the executed command ``y`` (turn odometry for the memories), advance."""
        dt = 1.0 / self.p.hz
        turn = float(y[2]) * dt
        self.ball_bearing = math.remainder(self.ball_bearing - turn, math.tau)
        self.goal_bearing = math.remainder(self.goal_bearing - turn, math.tau)
        self.turned += abs(turn)
        self.tick += 1
        self.state_ticks += 1

    # --- subtasks ------------------------------------------------------------------------

    def _seek(self, y: np.ndarray, x: np.ndarray, dt: float) -> None:
        p = self.p
        self._label = "seek"
        t = self.state_ticks * dt
        y[4] = p.seek_pan_amp * math.sin(2 * math.pi * t / p.seek_pan_period)
        if self.wander_ticks > 0:
            self.wander_ticks -= 1
            y[0] = p.wander_speed
            if self.wander_ticks == 0:
                self.turned = 0.0
            return
        if self.turned >= 2 * math.pi + 0.5:
            self.wander_ticks = int(p.wander_time * p.hz)
            y[0] = p.wander_speed
            return
        direction = 1.0
        if self.ball_memory and self.ball_bearing < 0:
            direction = -1.0
        y[2] = direction * p.seek_turn

    def _trap(self, y: np.ndarray, x: np.ndarray, dt: float) -> None:
        p = self.p
        self._label = "trap"
        n_motion = round(self.motion.trap_time * p.hz)
        if self.motion_ticks >= 0:
            # the trap motion runs; the robot ignores walk and head commands meanwhile
            self.motion_ticks += 1
            y[3:6] = (math.radians(-60.0), 0.0, math.radians(-10.0))
            if self.motion_ticks < n_motion - 1:
                y[8] = encode_indicator("trap")
            if self.motion_ticks >= n_motion + 1:
                self._go("aim")
            return
        tilt, pan, nod = (float(v) for v in x[18:21])
        ball = x[self._ball]
        if ball[2] <= 0:
            # momentarily lost: turn towards its remembered bearing, head where it was
            y[2] = float(
                np.clip(p.approach_turn_gain * self.ball_bearing, -p.seek_turn, p.seek_turn)
            )
            y[3:6] = (tilt, pan, nod)
            return
        fwd, left = self.head.ball_position(
            ball[0], ball[1], ball[2], tilt, pan, nod, p.ball_radius
        )
        bearing = math.atan2(left, fwd)
        dist = math.hypot(fwd, left)
        # head tracks the ball (proportional servo in image coordinates)
        fn = self.head.fn
        y[3] = tilt + p.head_track_gain * math.atan(ball[1] / fn)
        y[4] = pan - p.head_track_gain * math.atan(ball[0] / fn)
        y[5] = 0.0
        lo, hi = p.trap_forward
        if lo <= fwd <= hi and abs(left) <= p.trap_left:
            self.motion_ticks = 0
            y[8] = encode_indicator("trap")
            return
        y[2] = float(np.clip(p.approach_turn_gain * bearing, -p.seek_turn, p.seek_turn))
        if abs(bearing) < 0.6:
            target = 0.5 * (lo + hi)
            speed = p.approach_speed if dist > p.approach_slow_dist else p.approach_slow_speed
            y[0] = float(np.clip(1.5 * (fwd - target), -0.06, speed))
            if dist < 2 * p.approach_slow_dist:
                y[1] = float(np.clip(p.approach_side_gain * left, -0.1, 0.1))

    def _aim(self, y: np.ndarray, x: np.ndarray, dt: float) -> None:
        p = self.p
        self._label = "aim"
        goal = x[self._goal]
        if self.state_ticks * dt >= p.aim_timeout:
            self._go("kick")
            self._kick(y, x, dt)
            return
        if goal[2] > 0:
            b = self.goal_bearing
            if abs(b) < p.aim_tolerance:
                self.settle += 1
                if self.settle >= p.aim_settle_ticks:
                    self._go("kick")
                    self._kick(y, x, dt)
                    return
            else:
                self.settle = 0
            y[2] = float(np.clip(p.aim_turn_gain * b, -p.aim_turn, p.aim_turn))
        else:
            self.settle = 0
            direction = 1.0 if (not self.goal_memory or self.goal_bearing >= 0) else -1.0
            y[2] = direction * p.aim_turn

    def _kick(self, y: np.ndarray, x: np.ndarray, dt: float) -> None:
        p = self.p
        self._label = "kick"
        n_motion = round(self.motion.kick_time * p.hz)
        self.motion_ticks = max(self.motion_ticks, 0)
        if self.motion_ticks < n_motion - 1:
            y[8] = encode_indicator("kick")
        self.motion_ticks += 1
        if self.motion_ticks >= n_motion + 3:
            self._go("seek")

    _label: str = "seek"


assert set(SUBTASKS) == {"seek", "trap", "aim", "kick"}
assert COLOURS[0] == "ball"
