"""Parameters of the AIBO soccer simulator: field, ball, robot, camera, motions, episodes.

Every number is a field of a frozen dataclass with a documented default; the sources are
in ``docs/aibo-simulation.md`` (section numbers in the comments). A TOML file
(``configs/aibo.toml``) can override any field, table by table; unknown keys are an error.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from dataclasses import field as _dfield
from pathlib import Path
from typing import Any

__all__ = [
    "BallConfig",
    "CameraConfig",
    "SimConfigError",
    "EpisodeConfig",
    "FieldConfig",
    "MotionConfig",
    "RobotConfig",
    "SimConfig",
    "VisionNoiseConfig",
    "WalkConfig",
    "load_config",
]


class SimConfigError(ValueError):
    """A simulator or task configuration value or key that is not acceptable (the daemon's
    config errors are :class:`roger_daemon.config.ConfigError`)."""


def _positive(obj: object, *names: str) -> None:
    for n in names:
        v = getattr(obj, n)
        if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
            raise SimConfigError(f"{type(obj).__name__}.{n} must be a finite number > 0, got {v!r}")


def _non_negative(obj: object, *names: str) -> None:
    for n in names:
        v = getattr(obj, n)
        if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
            raise SimConfigError(
                f"{type(obj).__name__}.{n} must be a finite number >= 0, got {v!r}")


@dataclass(frozen=True)
class FieldConfig:
    """RoboCup 4-legged field, 2005 rules (docs/aibo-simulation.md §2). Metres; +x at ``attack``."""

    length: float = 5.4  # between the goal lines
    width: float = 3.6  # between the sidelines
    fringe_side: float = 0.2  # carpet beyond the sidelines
    fringe_end: float = 0.3  # carpet beyond the goal lines (= goal depth)
    goal_width: float = 0.8
    goal_depth: float = 0.3
    goal_height: float = 0.3
    goal_wall: float = 0.02  # thickness of the goal's walls
    border_height: float = 0.1  # low white border at the carpet edge (keeps the robot in)
    beacon_radius: float = 0.05
    beacon_outside: float = 0.15  # beacon axis outside the sideline
    beacon_from_goal_line: float = 1.35
    beacon_white: float = 0.2  # white bottom band height
    beacon_band: float = 0.1  # height of each colour band (upper border at 0.4 m)
    attack: str = "blue"  # the opponent goal's colour, at +x; the own goal is the other colour

    def __post_init__(self) -> None:
        _positive(self, "length", "width", "goal_width", "goal_depth", "goal_height", "goal_wall")
        _positive(self, "beacon_radius", "beacon_band", "beacon_white", "border_height")
        _non_negative(self, "fringe_side", "fringe_end", "beacon_outside", "beacon_from_goal_line")
        if self.attack not in ("blue", "yellow"):
            raise SimConfigError(
                f"FieldConfig.attack must be 'blue' or 'yellow', got {self.attack!r}")
        if self.goal_width >= self.width:
            raise SimConfigError("FieldConfig.goal_width must be smaller than the field width")


@dataclass(frozen=True)
class BallConfig:
    """Orange ball (docs/aibo-simulation.md §2 and §4.4)."""

    radius: float = 0.042
    mass: float = 0.03  # UNVERIFIED; the [MEAS] calibration used 0.03 kg
    rolling_friction: float = 0.006  # docs/aibo-simulation.md §4.4: 0.004-0.006
    spinning_friction: float = 0.006
    lateral_friction: float = 0.5
    restitution: float = 0.5
    # pybullet's default damping (0.04) adds a speed-proportional drag that makes the roll
    # distance far from quadratic in the launch speed; without it a ball launched rolling at
    # v travels 0.99 v^2 m (measured, 0.5-2.5 m/s), which the kick model inverts.
    linear_damping: float = 0.0
    angular_damping: float = 0.0

    def __post_init__(self) -> None:
        _positive(self, "radius", "mass")
        _non_negative(self, "rolling_friction", "spinning_friction", "lateral_friction")
        _non_negative(self, "restitution", "linear_damping", "angular_damping")


@dataclass(frozen=True)
class WalkConfig:
    """Walk engine limits (docs/aibo-simulation.md §1.5: Tekkotsu WalkMC's faster values).

    Speeds in m/s and rad/s; ``accel_factor`` x the limit per second is the acceleration limit
    (Tekkotsu uses 2x). ``noise`` is the seeded relative standard deviation of the executed
    velocity per tick (odometry noise).
    """

    max_forward: float = 0.225
    max_backward: float = 0.18
    max_side: float = 0.17
    max_turn: float = 2.1
    accel_factor: float = 2.0
    noise: float = 0.05
    max_force: float = 300.0  # N, of the constraint that carries the body

    def __post_init__(self) -> None:
        _positive(self, "max_forward", "max_backward", "max_side", "max_turn", "accel_factor")
        _positive(self, "max_force")
        _non_negative(self, "noise")


@dataclass(frozen=True)
class RobotConfig:
    """ERS-7-like body from primitives (docs/aibo-simulation.md §1.1-§1.3). Angles in degrees here.

    The trunk is level (the real stance pitches it ~14 deg nose down; omitted), so with the
    head at zero the camera sits ``trunk_height + 0.0195 + 0.08 + 0.0146`` ~= 0.23 m high.
    """

    trunk_length: float = 0.22
    trunk_width: float = 0.13
    trunk_thickness: float = 0.07
    trunk_height: float = 0.12  # height of the trunk centre above the floor
    leg_x: float = 0.065
    leg_y: float = 0.0625
    leg_size: float = 0.03
    mass: float = 1.6  # UNVERIFIED (commonly quoted)
    neck_base: tuple[float, float] = (0.0675, 0.0195)  # tilt1 pivot (forward, up) of the centre
    neck_length: float = 0.08  # tilt1 -> pan/nod
    camera_offset: tuple[float, float] = (0.0811, 0.0146)  # camera in the nod frame (fwd, up)
    tilt_range: tuple[float, float] = (-75.0, 0.0)  # positive looks up
    pan_range: tuple[float, float] = (-88.0, 88.0)  # positive looks left
    nod_range: tuple[float, float] = (-15.0, 45.0)  # positive looks up
    tail_pan_range: tuple[float, float] = (-45.0, 45.0)
    tail_tilt_range: tuple[float, float] = (5.0, 60.0)
    tilt_speed: float = 3.19  # rad/s, Sony's maxima (docs/aibo-simulation.md §1.3)
    pan_speed: float = 10.1
    nod_speed: float = 5.78
    tail_speed: float = 15.2

    def __post_init__(self) -> None:
        _positive(self, "trunk_length", "trunk_width", "trunk_thickness", "trunk_height")
        _positive(self, "leg_x", "leg_y", "leg_size", "mass", "neck_length")
        _positive(self, "tilt_speed", "pan_speed", "nod_speed", "tail_speed")
        for n in ("tilt_range", "pan_range", "nod_range", "tail_pan_range", "tail_tilt_range"):
            lo, hi = getattr(self, n)
            if not lo < hi:
                raise SimConfigError(f"RobotConfig.{n} must be (low, high) with low < high")
        if self.trunk_height - self.trunk_thickness / 2 <= 0:
            raise SimConfigError("RobotConfig: the trunk must be above the floor")


@dataclass(frozen=True)
class CameraConfig:
    """Head camera (docs/aibo-simulation.md §1.4): 208x160, HFOV 56.9 deg, square pixels."""

    width: int = 208
    height: int = 160
    hfov: float = 56.9  # degrees; the vertical FOV follows from the aspect ratio
    near: float = 0.02
    far: float = 8.0
    min_pixels: float = 4.0  # at 208x160; scaled with the image area at other resolutions

    def __post_init__(self) -> None:
        if not (isinstance(self.width, int) and isinstance(self.height, int)):
            raise SimConfigError("CameraConfig.width/height must be integers")
        if not (8 <= self.width <= 2048 and 8 <= self.height <= 2048):
            raise SimConfigError("CameraConfig.width/height must be in 8..2048")
        _positive(self, "hfov", "near", "far", "min_pixels")
        if self.hfov >= 170:
            raise SimConfigError("CameraConfig.hfov must be < 170 degrees")

    @property
    def focal_px(self) -> float:
        """Focal length in pixels of this resolution."""
        return (self.width / 2) / math.tan(math.radians(self.hfov) / 2)

    @property
    def vfov(self) -> float:
        """Vertical field of view in degrees (square pixels)."""
        return math.degrees(2 * math.atan((self.height / 2) / self.focal_px))

    @property
    def min_area_fraction(self) -> float:
        """Smallest blob, as a fraction of the image, reported as seen."""
        return self.min_pixels / (208.0 * 160.0)


@dataclass(frozen=True)
class VisionNoiseConfig:
    """Seeded blob noise: per-colour dropout per frame, centroid jitter, relative size jitter."""

    dropout: float = 0.02
    jitter: float = 0.004
    size_jitter: float = 0.02

    def __post_init__(self) -> None:
        _non_negative(self, "dropout", "jitter", "size_jitter")
        if self.dropout >= 1:
            raise SimConfigError("VisionNoiseConfig.dropout must be < 1")


@dataclass(frozen=True)
class MotionConfig:
    """Time-extended motions (docs/aibo-simulation.md §1.6, §4.3). Seconds, metres, degrees.

    Trap: the robot lunges forward for ``trap_lunge_time`` at ``trap_lunge_speed`` and lowers its
    head; at ``trap_capture_time`` a ball inside the capture box (robot frame, from the trunk
    centre) is taken under the chin and held at ``hold_x`` until a kick, or for at most
    ``hold_timeout`` (then dropped). Kick: at ``kick_release_time`` a held ball (or one inside the
    capture box) is launched along the body heading plus Gaussian heading noise, with a travel
    distance drawn from a normal distribution clipped to ``kick_distance_range``; the launch
    speed that travels that distance is ``sqrt(distance / kick_distance_per_speed2)``.
    """

    trap_time: float = 0.83
    trap_capture_time: float = 0.4
    trap_lunge_time: float = 0.35
    trap_lunge_speed: float = 0.15
    capture_x: tuple[float, float] = (0.09, 0.27)
    capture_y: float = 0.07
    hold_x: float = 0.135
    hold_timeout: float = 6.0  # UNVERIFIED; the rules penalise > 3 s
    kick_time: float = 0.8
    kick_release_time: float = 0.35
    kick_distance_mean: float = 2.15  # [UTK] mean travel 2.15 m
    kick_distance_sd: float = 0.55
    kick_distance_range: tuple[float, float] = (0.5, 4.05)  # [UTK] longest 4.05 m
    kick_heading_sd: float = 10.0  # degrees; docs/aibo-simulation.md §4.3: sigma ~ 10-15
    kick_distance_per_speed2: float = 0.99  # m per (m/s)^2, measured for BallConfig defaults

    def __post_init__(self) -> None:
        _positive(self, "trap_time", "trap_capture_time", "kick_time", "kick_release_time")
        _positive(self, "hold_x", "hold_timeout", "kick_distance_mean", "capture_y")
        _positive(self, "kick_distance_per_speed2")
        _non_negative(self, "trap_lunge_time", "trap_lunge_speed", "kick_distance_sd")
        _non_negative(self, "kick_heading_sd")
        if self.trap_capture_time > self.trap_time or self.kick_release_time > self.kick_time:
            raise SimConfigError("MotionConfig: capture/release must happen within the motion")
        lo, hi = self.kick_distance_range
        if not 0 < lo < hi:
            raise SimConfigError("MotionConfig.kick_distance_range must be 0 < low < high")
        if not 0 < self.capture_x[0] < self.capture_x[1]:
            raise SimConfigError("MotionConfig.capture_x must be 0 < low < high")


@dataclass(frozen=True)
class EpisodeConfig:
    """Episode timing and start noise."""

    time_limit: float = 150.0  # seconds of sim time (paper: 2.5 minutes)
    control_hz: float = 30.0
    substeps: int = 8  # physics steps per control tick (240 Hz)
    start_xy_noise: float = 0.05  # m, sd of the robot's and the ball's start position
    start_heading_noise: float = 5.0  # degrees, sd

    def __post_init__(self) -> None:
        _positive(self, "time_limit", "control_hz")
        _non_negative(self, "start_xy_noise", "start_heading_noise")
        if not (isinstance(self.substeps, int) and 1 <= self.substeps <= 64):
            raise SimConfigError("EpisodeConfig.substeps must be an integer in 1..64")

    @property
    def dt(self) -> float:
        """Control period in seconds."""
        return 1.0 / self.control_hz


@dataclass(frozen=True)
class SimConfig:
    """Everything the simulator needs; ``vision`` is ``"rendered"`` or ``"fast"``."""

    field: FieldConfig = _dfield(default_factory=FieldConfig)
    ball: BallConfig = _dfield(default_factory=BallConfig)
    walk: WalkConfig = _dfield(default_factory=WalkConfig)
    robot: RobotConfig = _dfield(default_factory=RobotConfig)
    camera: CameraConfig = _dfield(default_factory=CameraConfig)
    noise: VisionNoiseConfig = _dfield(default_factory=VisionNoiseConfig)
    motion: MotionConfig = _dfield(default_factory=MotionConfig)
    episode: EpisodeConfig = _dfield(default_factory=EpisodeConfig)
    vision: str = "rendered"

    def __post_init__(self) -> None:
        if self.vision not in ("rendered", "fast"):
            raise SimConfigError(
                f"SimConfig.vision must be 'rendered' or 'fast', got {self.vision!r}")

    def with_overrides(self, data: Mapping[str, Any]) -> SimConfig:
        """A copy with tables from ``data`` (as in the TOML file) applied."""
        changes: dict[str, Any] = {}
        for name, value in data.items():
            if name == "vision":
                changes["vision"] = value
                continue
            sub = getattr(self, name, None) if name in _TABLES else None
            if sub is None:
                raise SimConfigError(f"unknown table [{name}] (known: {sorted(_TABLES)}, vision)")
            if not isinstance(value, Mapping):
                raise SimConfigError(f"[{name}] must be a table")
            changes[name] = _apply(sub, value, name)
        return replace(self, **changes)


_TABLES = ("field", "ball", "walk", "robot", "camera", "noise", "motion", "episode")


def _apply(obj: Any, values: Mapping[str, Any], table: str) -> Any:
    known = {f.name: f for f in fields(obj)}
    out: dict[str, Any] = {}
    for k, v in values.items():
        if k not in known:
            raise SimConfigError(f"unknown key {k!r} in [{table}] (known: {sorted(known)})")
        current = getattr(obj, k)
        if isinstance(current, tuple):
            if not isinstance(v, list | tuple) or len(v) != len(current):
                raise SimConfigError(f"[{table}] {k} must be a list of {len(current)} numbers")
            v = tuple(float(e) for e in v)
        elif isinstance(current, bool) or isinstance(current, str):
            if type(v) is not type(current):
                raise SimConfigError(f"[{table}] {k} must be a {type(current).__name__}")
        elif isinstance(current, int):
            if isinstance(v, bool) or not isinstance(v, int):
                raise SimConfigError(f"[{table}] {k} must be an integer")
        elif isinstance(current, float):
            if isinstance(v, bool) or not isinstance(v, int | float):
                raise SimConfigError(f"[{table}] {k} must be a number")
            v = float(v)
        out[k] = v
    return replace(obj, **out)


def load_config(path: str | Path | None = None, **overrides: Any) -> SimConfig:
    """Defaults, then the TOML file at ``path`` (if any), then ``overrides`` (field=value)."""
    cfg = SimConfig()
    if path is not None:
        with open(path, "rb") as f:
            data = tomllib.load(f)
        sim_data = data.get("sim", data)
        if not isinstance(sim_data, Mapping):
            raise SimConfigError("[sim] must be a table")
        cfg = cfg.with_overrides(sim_data)
    if overrides:
        cfg = replace(cfg, **overrides)
    return cfg
