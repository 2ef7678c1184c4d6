"""The hand-coded controller (HCC): a memory-free seek / trap / aim / kick demonstrator.

It acts only on the 23-D perception (``protocols/AIBO.md``) plus its own state and timers,
like the paper's controller on the real robot (section IV, Fig. 6a). It knows its own body
(head kinematics, camera model, motion durations), but never sees the world's ground truth.

**Every subtask's policy is a function of the current perception alone**; the FSM's memory
(remembered bearings, timers, turn odometry) decides only the *transitions*. Where the paper's
FSM needs memory to act (which way to turn), the direction is its own labelled subtask, chosen
at entry. That is what makes each subtask a unimap of perception (the paper's premise,
section III: a subtask is learnable in isolation); ``docs/demonstrator.md`` explains it.

Subtasks (labels reported with every action; :data:`COARSE` maps them to the paper's four):

* ``seek_left`` / ``seek_right`` (paper: seek): the ball is not seen; turn in place that way,
  head in the *look pose*. The side is the ball's remembered bearing at entry. After a full
  turn without the ball -> ``wander``: walk straight ahead (look pose) for a while, then seek.
* ``approach`` (paper: trap): walk to the ball; the head tracks it, the body turns to it,
  slower when close. Ball momentarily lost: turn towards where the head points. The ball
  lost for ``ball_lost_time`` -> seek; the ball inside the capture zone -> ``trap``.
* ``trap`` (paper: trap): the trap motion, action indicator = trap *held for the whole motion*
  (head down, walk 0), a constant the experts can learn (a one-tick trigger is not, issue 13).
  Motion done (timer) -> aim.
* ``aim_left`` / ``aim_right`` / ``aim`` (paper: aim): the ball is held under the chin, out of
  view, head in the look pose. Goal not seen: pivot round the ball towards the goal's
  remembered side (chosen at entry); goal seen: turn to centre it; centred for a few ticks
  -> kick. A ball seen in front means the trap failed -> approach. Timeout -> kick.
* ``kick`` (paper: kick): the kick motion, action indicator = kick while the ball is not seen
  (held under the chin), none once the released ball is in view (those perceptions are the
  approach's, which must not learn to kick); motion done -> seek.

Perceptual aliasing (the paper's multimap): seek, aim and kick all hold the look pose and see
no ball, so the same perception is met while turning to find the ball, pivoting to the goal
and kicking. The tail stands still (a constant command), so it leaks nothing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from protocols.aibo import COLOURS, DIMS, SUBTASKS, blob_slice, encode_indicator
from simulator.config import MotionConfig
from simulator.head_model import HeadModel

__all__ = ["COARSE", "HCC", "LABELS", "HCCParams", "HeadModel", "coarse_label"]

#: The demonstrator's subtask labels, and the paper's subtask each belongs to (Fig. 6a).
COARSE: dict[str, str] = {
    "seek_left": "seek", "seek_right": "seek", "wander": "seek",
    "approach": "trap", "trap": "trap",
    "aim_left": "aim", "aim_right": "aim", "aim": "aim",
    "kick": "kick",
}
LABELS: tuple[str, ...] = tuple(COARSE)


def coarse_label(label: str) -> str:
    """The paper's subtask (seek, trap, aim, kick) of a demonstrator label (itself if unknown)."""
    return COARSE.get(label, label)


@dataclass(frozen=True)
class HCCParams:
    """Thresholds, gains and timers of the FSM (seconds, metres, radians unless noted)."""

    hz: float = 30.0
    attack: str = "blue"  # opponent goal colour
    ball_radius: float = 0.042
    # look pose: seek, aim and kick hold it (the aliasing of section IV)
    look_tilt: float = math.radians(-15.0)
    look_nod: float = 0.0
    # seek
    see_ticks: int = 2
    seek_turn: float = 1.5
    wander_time: float = 2.5
    wander_speed: float = 0.2
    # approach (paper: trap) and the trap motion
    ball_lost_time: float = 0.6
    approach_turn_gain: float = 2.5
    approach_speed: float = 0.22
    approach_slow_dist: float = 0.45
    approach_slow_speed: float = 0.09
    approach_side_gain: float = 1.5
    trap_forward: tuple[float, float] = (0.17, 0.27)  # ball x in the body frame to trigger
    trap_left: float = 0.035
    head_track_gain: float = 0.6
    trap_head: tuple[float, float, float] = (math.radians(-60.0), 0.0, math.radians(-10.0))
    # aim: pivot round the held ball (turn + side step), or centre a goal in view
    aim_turn: float = 1.2
    aim_side: float = 0.1
    aim_turn_gain: float = 2.5
    aim_tolerance: float = math.radians(5.0)
    aim_settle_ticks: int = 3
    aim_timeout: float = 5.0
    aim_trap_failed_time: float = 0.5
    # tail: a constant command (no state, no clock)
    tail_tilt: float = math.radians(20.0)

    def __post_init__(self) -> None:
        if self.attack not in ("blue", "yellow"):
            raise ValueError(f"HCCParams.attack must be 'blue' or 'yellow', got {self.attack!r}")
        for name in ("hz", "seek_turn", "aim_turn", "aim_timeout", "approach_speed"):
            if not getattr(self, name) > 0:
                raise ValueError(f"HCCParams.{name} must be > 0")


_SEEK = ("seek_left", "seek_right", "wander")
_AIM = ("aim_left", "aim_right", "aim")


class HCC:
    """The FSM. ``act(x)`` -> (9-D action, subtask label); ``reset()`` between episodes.

    :meth:`decide` runs the transitions (memory and timers) and then the current subtask's
    policy (:meth:`policy`, a function of the perception only); it does not commit. For the
    transitioner, :meth:`commit` tells the FSM which command was actually executed (it
    integrates its own turn commands to remember where the ball and the goal were).
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
        # motion lengths in ticks: the world ends a motion after ceil(time * hz) steps, and a
        # trap/kick indicator after that would start a new motion
        self.n_trap = math.ceil(self.motion.trap_time * self.p.hz - 1e-9)
        self.n_kick = math.ceil(self.motion.kick_time * self.p.hz - 1e-9)
        self.transitions: list[tuple[int, str, str]] = []
        self.reset()

    # --- state -------------------------------------------------------------------------

    def reset(self) -> None:
        """Back to seek, clear memories and timers."""
        self.state = "seek_left"
        self.tick = 0
        self.state_ticks = 0
        self.aim_ticks = 0  # ticks in the aim family (aim_left/aim_right/aim)
        self.seen_ticks = 0
        self.unseen_ticks = 0
        self.ball_bearing = 0.0  # remembered bearing of the ball (rad, body frame)
        self.goal_bearing = 0.0  # remembered bearing of the opponent goal
        self.goal_memory = False
        self.turned = 0.0  # |turn| accumulated in the current seek sweep
        self.settle = 0
        self.transitions = []

    def _go(self, state: str) -> None:
        if state != self.state:
            self.transitions.append((self.tick, self.state, state))
            if state in _AIM and self.state not in _AIM:
                self.aim_ticks = 0
            self.state = state
            self.state_ticks = 0
            self.settle = 0
            self.turned = 0.0

    def _seek_side(self) -> str:
        return "seek_right" if self.ball_bearing < 0 else "seek_left"

    def _aim_side(self) -> str:
        return "aim_right" if self.goal_memory and self.goal_bearing < 0 else "aim_left"

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
        self._remember(x)
        self._transition(x)
        return self.policy(self.state, x), self.state

    def _remember(self, x: np.ndarray) -> None:
        """Update the memories (used by transitions only) from the perception."""
        tilt, pan, nod = (float(v) for v in x[18:21])
        ball, goal, own = x[self._ball], x[self._goal], x[self._own]
        ball_seen = ball[2] > 0
        self.seen_ticks = self.seen_ticks + 1 if ball_seen else 0
        self.unseen_ticks = 0 if ball_seen else self.unseen_ticks + 1
        if ball_seen:
            self.ball_bearing = self.head.bearing(ball[0], ball[1], tilt, pan, nod)
        if goal[2] > 0:
            self.goal_bearing = self.head.bearing(goal[0], goal[1], tilt, pan, nod)
            self.goal_memory = True
        elif own[2] > 0:
            own_b = self.head.bearing(own[0], own[1], tilt, pan, nod)
            self.goal_bearing = math.remainder(own_b + math.pi, math.tau)
            self.goal_memory = True

    def _transition(self, x: np.ndarray) -> None:
        """The FSM's transitions (section IV, Fig. 6a): memory and timers live only here."""
        p = self.p
        dt = 1.0 / p.hz
        s = self.state
        if s in _SEEK:
            if self.seen_ticks >= p.see_ticks:
                self._go("approach")
            elif s == "wander" and self.state_ticks * dt >= p.wander_time:
                self._go(self._seek_side())
            elif s != "wander" and self.turned >= 2 * math.pi + 0.5:
                self._go("wander")
        elif s == "approach":
            if self.unseen_ticks * dt >= p.ball_lost_time:
                self._go(self._seek_side())
            elif self.ball_in_zone(x):
                self._go("trap")
        elif s == "trap":
            if self.state_ticks >= self.n_trap:
                self._go(self._aim_side())
        elif s in _AIM:
            self._aim_transition(x)
        elif s == "kick" and self.state_ticks >= self.n_kick:
            self._go(self._seek_side())

    def _aim_transition(self, x: np.ndarray) -> None:
        p = self.p
        dt = 1.0 / p.hz
        if self.seen_ticks > 0 and self.aim_ticks * dt > p.aim_trap_failed_time:
            self._go("approach")  # the ball is in front of us: the trap failed
            return
        if self.aim_ticks * dt >= p.aim_timeout:
            self._go("kick")
            return
        if x[self._goal][2] <= 0:
            if self.state == "aim":
                self._go(self._aim_side())
            return
        self._go("aim")
        if abs(self.goal_bearing) < p.aim_tolerance:
            self.settle += 1
            if self.settle >= p.aim_settle_ticks:
                self._go("kick")
        else:
            self.settle = 0

    def commit(self, y: np.ndarray) -> None:
        """Account for the executed command ``y`` (turn odometry for the memories), advance."""
        dt = 1.0 / self.p.hz
        turn = float(y[2]) * dt
        self.ball_bearing = math.remainder(self.ball_bearing - turn, math.tau)
        self.goal_bearing = math.remainder(self.goal_bearing - turn, math.tau)
        self.turned += abs(turn)
        self.tick += 1
        self.state_ticks += 1
        if self.state in _AIM:
            self.aim_ticks += 1

    # --- perception-only helpers and the subtask policies --------------------------------

    def ball_in_zone(self, x: np.ndarray) -> bool:
        """Is the seen ball inside the trap's trigger zone (body frame, from the perception)?"""
        ball = x[self._ball]
        if ball[2] <= 0:
            return False
        tilt, pan, nod = (float(v) for v in x[18:21])
        fwd, left = self.head.ball_position(
            ball[0], ball[1], ball[2], tilt, pan, nod, self.p.ball_radius
        )
        lo, hi = self.p.trap_forward
        return lo <= fwd <= hi and abs(left) <= self.p.trap_left

    def policy(self, subtask: str, x: np.ndarray) -> np.ndarray:
        """The 9-D action of ``subtask`` on perception ``x``: no memory, no timers."""
        p = self.p
        y = np.zeros(DIMS.y)
        y[3:6] = (p.look_tilt, 0.0, p.look_nod)
        y[7] = p.tail_tilt
        if subtask == "seek_left":
            y[2] = p.seek_turn
        elif subtask == "seek_right":
            y[2] = -p.seek_turn
        elif subtask == "wander":
            y[0] = p.wander_speed
        elif subtask == "approach":
            self._approach(y, x)
        elif subtask == "trap":
            y[3:6] = p.trap_head
            y[8] = encode_indicator("trap")
        elif subtask in ("aim_left", "aim_right"):
            side = 1.0 if subtask == "aim_left" else -1.0
            y[1] = -side * p.aim_side
            y[2] = side * p.aim_turn
        elif subtask == "aim":
            self._aim(y, x)
        elif subtask == "kick":
            if x[self._ball][2] <= 0:  # the ball seen again means it has been released
                y[8] = encode_indicator("kick")
        else:
            raise ValueError(f"unknown subtask {subtask!r}; expected one of {LABELS}")
        return y

    def _approach(self, y: np.ndarray, x: np.ndarray) -> None:
        p = self.p
        tilt, pan, nod = (float(v) for v in x[18:21])
        ball = x[self._ball]
        if ball[2] <= 0:
            # momentarily lost: the head still points where it was; turn that way
            y[2] = float(np.clip(p.approach_turn_gain * pan, -p.seek_turn, p.seek_turn))
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
        y[2] = float(np.clip(p.approach_turn_gain * bearing, -p.seek_turn, p.seek_turn))
        if abs(bearing) < 0.6:
            lo, hi = p.trap_forward
            target = 0.5 * (lo + hi)
            speed = p.approach_speed if dist > p.approach_slow_dist else p.approach_slow_speed
            y[0] = float(np.clip(1.5 * (fwd - target), -0.06, speed))
            if dist < 2 * p.approach_slow_dist:
                y[1] = float(np.clip(p.approach_side_gain * left, -0.1, 0.1))

    def _aim(self, y: np.ndarray, x: np.ndarray) -> None:
        p = self.p
        goal = x[self._goal]
        if goal[2] <= 0:
            return
        tilt, pan, nod = (float(v) for v in x[18:21])
        b = self.head.bearing(goal[0], goal[1], tilt, pan, nod)
        y[2] = float(np.clip(p.aim_turn_gain * b, -p.aim_turn, p.aim_turn))
        y[1] = -p.aim_side * y[2] / p.aim_turn


assert set(SUBTASKS) == set(COARSE.values())
assert COLOURS[0] == "ball"
