"""Episodes: the 13 start locations, seeding, termination, and an in-process runner.

:class:`SoccerSim` is the whole simulator behind one small interface (reset, perceive, step,
outcome) with no I/O; the Zenoh node (``simulator/sim_node.py``), the benchmark, the plots and
the tests all drive it. An episode is fully determined by (config, location, seed,
repetition) and the commands it receives: the world is rebuilt on every reset and every
random draw comes from generators spawned from ``SeedSequence([seed, location, repetition])``.

Outcomes: ``goal`` (the whole ball behind the opponent's goal line, between the posts, below
the crossbar: success), ``own_goal``, ``out`` (the whole ball over a sideline, or over a goal
line outside the goal), ``timeout`` (``EpisodeConfig.time_limit`` of sim time, 150 s).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from protocols.aibo import DIMS
from simulator.config import SimConfig
from simulator.vision import apply_noise, make_vision
from simulator.world import World

__all__ = [
    "OUTCOMES",
    "START_LOCATIONS",
    "Controller",
    "EpisodeResult",
    "SoccerSim",
    "StartLocation",
    "Trace",
    "episode_streams",
    "parse_locations",
    "run_episode",
]

OUTCOMES = ("goal", "own_goal", "out", "timeout", "stopped")


@dataclass(frozen=True)
class StartLocation:
    """Robot pose (x, y in m, heading in degrees; 0 faces the opponent goal) and ball position."""

    index: int
    name: str
    robot: tuple[float, float, float]
    ball: tuple[float, float]
    note: str


#: Spread over the whole field like the paper's Fig. 6b (whose exact poses are not published):
#: five columns from the opponent's half (x = 2) to the own half (x = -2). Some starts see the
#: ball at once, others must seek it first (ball beside or behind the robot).
START_LOCATIONS: tuple[StartLocation, ...] = (
    StartLocation(0, "near-centre", (1.0, 0.0, 0.0), (1.5, 0.0), "ball ahead, 1.2 m from goal"),
    StartLocation(1, "near-left", (2.0, 1.2, -90.0), (2.0, 0.6), "ball ahead, goal to the left"),
    StartLocation(2, "near-right", (2.0, -1.2, 90.0), (2.0, -0.6), "ball ahead, goal to the right"),
    StartLocation(3, "goal-mouth", (2.0, 0.0, 180.0), (2.2, 0.3), "back to the goal, ball behind"),
    StartLocation(4, "mid-left", (1.0, 0.6, 0.0), (1.4, 1.1), "ball ahead-left, off camera"),
    StartLocation(5, "mid-right", (1.0, -0.6, 0.0), (1.4, -1.1), "ball ahead-right, off camera"),
    StartLocation(6, "centre", (0.0, 0.0, 0.0), (0.6, 0.0), "ball ahead, 2.1 m from goal"),
    StartLocation(7, "centre-left", (0.0, 1.2, 0.0), (0.5, 0.8), "ball ahead-right"),
    StartLocation(
        8,
        "centre-right",
        (0.0, -1.2, 90.0),
        (0.5, -0.8),
        "facing across the field, ball right, off camera",
    ),
    StartLocation(9, "own-left", (-1.0, 0.6, 0.0), (-0.4, 0.6), "own half, ball ahead"),
    StartLocation(
        10, "own-right", (-1.0, -0.6, 180.0), (-0.4, -0.3), "facing the own goal, ball behind"
    ),
    StartLocation(
        11, "deep-centre", (-2.0, 0.0, 0.0), (-1.4, 0.0), "deep in the own half, ball ahead"
    ),
    StartLocation(12, "deep-left", (-2.0, 1.2, -45.0), (-1.5, 0.5), "deep, ball ahead-right"),
)


def parse_locations(text: str) -> list[int]:
    """``"all"`` or a comma list of indices/ranges (``"0,3,7"``, ``"0-4,9"``) -> indices."""
    text = text.strip()
    if text in ("", "all"):
        return list(range(len(START_LOCATIONS)))
    out: list[int] = []
    for part in text.split(","):
        part = part.strip()
        if "-" in part:
            a, b = part.split("-", 1)
            out.extend(range(int(a), int(b) + 1))
        else:
            out.append(int(part))
    for i in out:
        if not 0 <= i < len(START_LOCATIONS):
            raise ValueError(f"location {i} not in 0..{len(START_LOCATIONS) - 1}")
    return out


def episode_streams(seed: int, location: int, repetition: int) -> list[np.random.Generator]:
    """Four independent generators (start noise, walk noise, vision noise, kicks)."""
    ss = np.random.SeedSequence([int(seed) & 0xFFFFFFFF, int(location), int(repetition)])
    return [np.random.default_rng(s) for s in ss.spawn(4)]


@dataclass
class EpisodeResult:
    """One finished episode (what ``roger sim`` publishes and writes to ``--results``)."""

    episode: int
    location: int
    repetition: int
    seed: int
    outcome: str
    success: bool
    sim_time_s: float
    ticks: int
    counters: dict[str, int] = field(default_factory=dict)
    path_m: float = 0.0  # ground truth: how far the robot's body walked
    ball_path_m: float = 0.0  # and how far the ball rolled

    def to_map(self) -> dict[str, Any]:
        """Plain JSON/msgpack map."""
        return {
            "episode": self.episode,
            "location": self.location,
            "location_name": (START_LOCATIONS[self.location].name
                              if 0 <= self.location < len(START_LOCATIONS) else ""),
            "repetition": self.repetition,
            "seed": self.seed,
            "outcome": self.outcome,
            "success": self.success,
            "sim_time_s": round(self.sim_time_s, 4),
            "ticks": self.ticks,
            "path_m": round(self.path_m, 3),
            "ball_path_m": round(self.ball_path_m, 3),
            **{k: int(v) for k, v in self.counters.items()},
        }


class SoccerSim:
    """World + vision + termination, stepped one control tick at a time."""

    def __init__(self, cfg: SimConfig | None = None, vision: str | None = None) -> None:
        self.cfg = cfg or SimConfig()
        self.world = World(self.cfg)
        self.vision = make_vision(self.world, self.cfg.camera, vision or self.cfg.vision)
        self.outcome: str | None = None
        self.location = 0
        self.seed = 0
        self.repetition = 0
        self.path_m = 0.0
        self.ball_path_m = 0.0
        self._xy = (0.0, 0.0, 0.0, 0.0)  # robot x, y and ball x, y after the last step
        self._vision_rng = np.random.default_rng(0)

    @property
    def ticks(self) -> int:
        """Control ticks since the reset."""
        return self.world.tick

    @property
    def time(self) -> float:
        """Sim time since the reset, in seconds."""
        return self.world.tick * self.cfg.episode.dt

    def close(self) -> None:
        """Release the pybullet client."""
        self.world.close()

    def reset(self, location: int, seed: int, repetition: int = 0,
              start: StartLocation | None = None) -> np.ndarray:
        """Start an episode from ``START_LOCATIONS[location]`` (or from ``start``, e.g. a pose
        of a ``--start-poses`` file, seeded as location ``location``); returns the first
        perception."""
        loc = START_LOCATIONS[location] if start is None else start
        start_rng, walk, vis, kick = episode_streams(seed, location, repetition)
        e = self.cfg.episode
        n = start_rng.standard_normal(5)
        rx = loc.robot[0] + e.start_xy_noise * n[0]
        ry = loc.robot[1] + e.start_xy_noise * n[1]
        heading = math.radians(loc.robot[2] + e.start_heading_noise * n[2])
        bx = loc.ball[0] + e.start_xy_noise * n[3]
        by = loc.ball[1] + e.start_xy_noise * n[4]
        self.world.reset((rx, ry, heading), (bx, by), walk, kick)
        self._vision_rng = vis
        self.outcome = None
        self.location, self.seed, self.repetition = location, seed, repetition
        self.path_m = self.ball_path_m = 0.0
        self._xy = self._positions()
        return self.perceive()

    def perceive(self) -> np.ndarray:
        """The 23-D perception of the current state (vision noise drawn here)."""
        blobs = apply_noise(self.vision.blobs(), self._vision_rng, self.cfg.noise)
        x = np.concatenate([blobs.ravel(), self.world.joint_angles()])
        assert x.shape == (DIMS.x,)
        return x

    def step(self, y: np.ndarray) -> str | None:
        """Execute command ``y`` for one tick; returns the outcome if the episode just ended."""
        if self.outcome is not None:
            raise RuntimeError("episode is over; call reset()")
        self.world.step(np.asarray(y, dtype=np.float64))
        rx, ry, bx, by = self._xy
        self._xy = self._positions()
        self.path_m += math.hypot(self._xy[0] - rx, self._xy[1] - ry)
        self.ball_path_m += math.hypot(self._xy[2] - bx, self._xy[3] - by)
        self.outcome = self._check()
        return self.outcome

    def _positions(self) -> tuple[float, float, float, float]:
        rx, ry, _ = self.world.robot_pose()
        bx, by, _ = self.world.ball_position()
        return rx, ry, bx, by

    def stop(self) -> None:
        """End the episode early (shutdown)."""
        if self.outcome is None:
            self.outcome = "stopped"

    def _check(self) -> str | None:
        f = self.cfg.field
        r = self.cfg.ball.radius
        bx, by, bz = self.world.ball_position()
        hl, hw = f.length / 2, f.width / 2
        if abs(bx) > hl + r:
            if abs(by) < f.goal_width / 2 and bz < f.goal_height:
                return "goal" if bx > 0 else "own_goal"
            return "out"
        if abs(by) > hw + r:
            return "out"
        if self.time >= self.cfg.episode.time_limit - 1e-9:
            return "timeout"
        return None

    def truth(self) -> dict[str, float]:
        """Ground truth for plots and logs: robot pose, ball position, held/motion flags."""
        x, y, yaw = self.world.robot_pose()
        bx, by, _ = self.world.ball_position()
        m = self.world.motion
        return {
            "robot_x": x,
            "robot_y": y,
            "robot_yaw": yaw,
            "ball_x": bx,
            "ball_y": by,
            "holding": float(self.world.holding),
            "motion": 0.0 if m is None else (1.0 if m.kind == "trap" else 2.0),
        }

    def result(self, episode: int = 0) -> EpisodeResult:
        """The result record of the current (finished) episode."""
        outcome = self.outcome or "stopped"
        return EpisodeResult(
            episode=episode,
            location=self.location,
            repetition=self.repetition,
            seed=self.seed,
            outcome=outcome,
            success=outcome == "goal",
            sim_time_s=self.time,
            ticks=self.ticks,
            counters=dict(self.world.counters),
            path_m=self.path_m,
            ball_path_m=self.ball_path_m,
        )


class Controller(Protocol):
    """What :func:`run_episode` drives: the HCC or anything with the same two methods."""

    def reset(self) -> None:
        """Start a new episode."""

    def act(self, x: np.ndarray) -> tuple[np.ndarray, str]:
        """The command and its label for one perception."""


@dataclass
class Trace:
    """Per-tick record of an episode (perception, command, label, ground truth)."""

    x: list[np.ndarray] = field(default_factory=list)
    y: list[np.ndarray] = field(default_factory=list)
    labels: list[str] = field(default_factory=list)
    truth: list[dict[str, float]] = field(default_factory=list)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(X (n, 23), Y (n, 9), labels (n,))."""
        return (
            np.array(self.x).reshape(-1, DIMS.x),
            np.array(self.y).reshape(-1, DIMS.y),
            np.array(self.labels, dtype=object),
        )


def run_episode(
    sim: SoccerSim,
    controller: Controller,
    location: int,
    seed: int,
    repetition: int = 0,
    episode: int = 0,
    trace: Trace | None = None,
    should_stop: Callable[[], bool] | None = None,
    start: StartLocation | None = None,
) -> EpisodeResult:
    """Run one episode in-process (no Zenoh): perceive, act, step until it ends."""
    x = sim.reset(location, seed, repetition, start)
    controller.reset()
    while True:
        y, label = controller.act(x)
        if trace is not None:
            trace.x.append(x)
            trace.y.append(np.asarray(y, dtype=np.float64))
            trace.labels.append(label)
            trace.truth.append(sim.truth())
        if sim.step(y) is not None:
            break
        if should_stop is not None and should_stop():
            sim.stop()
            break
        x = sim.perceive()
    return sim.result(episode)
