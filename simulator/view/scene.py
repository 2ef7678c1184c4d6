"""ROGER messages -> Foxglove messages: one converter for the live view and for MCAP files.

:class:`Converter` takes decoded ROGER messages (the maps of ``protocols.messages``, as
``roger echo --json`` prints them) with their log time and returns ``(topic, message)`` pairs:
Foxglove protobuf messages (``foxglove.messages``) for the panels that need a well-known schema,
plain dicts for JSON plot channels. :data:`TOPICS` lists every channel, its schema and what
produces it; :mod:`simulator.view.node` logs the pairs to a WebSocket server and/or an MCAP
file through the same ``foxglove`` context, so a recorded session looks the same as a live one.

The field, goals and beacons come from the task geometry (``simulator.config.FieldConfig``);
the robot's pose and the ball come from the simulator's ``truth`` episode events (``roger sim
--truth``); without them the scene shows the field only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from foxglove.messages import (
    CircleAnnotation,
    Color,
    CubePrimitive,
    CylinderPrimitive,
    FrameTransform,
    FrameTransforms,
    ImageAnnotations,
    Log,
    LogLevel,
    Point2,
    Pose,
    Quaternion,
    RawImage,
    SceneEntity,
    SceneUpdate,
    SpherePrimitive,
    TextAnnotation,
    Timestamp,
    Vector3,
)

from protocols.aibo import ACTION_NAMES, COLOURS
from simulator.config import FieldConfig

__all__ = ["TOPICS", "Converter"]

#: topic -> (schema, what it shows)
TOPICS: dict[str, tuple[str, str]] = {
    "/scene": ("foxglove.SceneUpdate", "field, goals, beacons, robot, ball (3D panel)"),
    "/tf": ("foxglove.FrameTransforms", "field -> robot (the robot's pose)"),
    "/camera/image": ("foxglove.RawImage", "the camera's colour blobs drawn as an image"),
    "/camera/blobs": ("foxglove.ImageAnnotations", "the colour blobs as circles with names"),
    "/roger/command": ("json", "the executed command, one field per action name"),
    "/roger/prediction": ("json", "the daemon's prediction: mean, var, std per action name"),
    "/roger/expert": ("json", "active expert, its majority label and the subtask"),
    "/roger/status": ("foxglove.Log", "the daemon's status as a log line at its level"),
    "/roger/events": ("foxglove.Log", "episode events (start, goal, timeout, ...)"),
}

CAMERA_W, CAMERA_H = 208, 160  # the default camera (protocols/AIBO.md)
BLOB_RGB = {
    "ball": (1.0, 0.5, 0.0), "yellow_goal": (1.0, 0.9, 0.0), "blue_goal": (0.1, 0.5, 1.0),
    "pink": (1.0, 0.4, 0.7), "yellow_beacon": (0.9, 0.8, 0.2), "blue_beacon": (0.2, 0.6, 0.9),
}
LEVELS = {"OK": LogLevel.Info, "WARN": LogLevel.Warning, "ERROR": LogLevel.Error,
          "STALE": LogLevel.Error}


def _ts(ns: int) -> Timestamp:
    return Timestamp(ns // 1_000_000_000, ns % 1_000_000_000)


def _color(rgb: tuple[float, float, float], a: float = 1.0) -> Color:
    return Color(r=rgb[0], g=rgb[1], b=rgb[2], a=a)


def _yaw(yaw: float) -> Quaternion:
    return Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))


def _pose(x: float, y: float, z: float, yaw: float = 0.0) -> Pose:
    return Pose(position=Vector3(x=x, y=y, z=z), orientation=_yaw(yaw))


def _cube(x: float, y: float, z: float, sx: float, sy: float, sz: float,
          rgb: tuple[float, float, float], yaw: float = 0.0) -> CubePrimitive:
    return CubePrimitive(pose=_pose(x, y, z, yaw), size=Vector3(x=sx, y=sy, z=sz),
                         color=_color(rgb))


def field_entity(f: FieldConfig, ns: int) -> SceneEntity:
    """The carpet, goals and beacons, in frame ``field`` (x towards the attacked goal)."""
    hl, hw = f.length / 2, f.width / 2
    cubes = [_cube(0, 0, -0.005, f.length + 2 * f.fringe_end, f.width + 2 * f.fringe_side,
                   0.01, (0.1, 0.55, 0.2)),
             _cube(0, 0, 0.001, 0.02, f.width, 0.002, (1, 1, 1))]  # the halfway line
    own = "yellow" if f.attack == "blue" else "blue"
    for sx, colour in ((1, f.attack), (-1, own)):
        rgb = BLOB_RGB[f"{colour}_goal"]
        gx = sx * (hl + f.goal_depth / 2)
        cubes.append(_cube(sx * (hl + f.goal_depth), 0, f.goal_height / 2, f.goal_wall,
                           f.goal_width, f.goal_height, rgb))
        for sy in (-1, 1):
            cubes.append(_cube(gx, sy * f.goal_width / 2, f.goal_height / 2, f.goal_depth,
                               f.goal_wall, f.goal_height, rgb))
    cylinders = []
    for sx in (-1, 1):
        goal = f.attack if sx > 0 else own
        for sy in (-1, 1):
            x = sx * (hl - f.beacon_from_goal_line)
            y = sy * (hw + f.beacon_outside)
            cylinders.append(CylinderPrimitive(
                pose=_pose(x, y, f.beacon_white / 2 + f.beacon_band),
                size=Vector3(x=2 * f.beacon_radius, y=2 * f.beacon_radius,
                             z=f.beacon_white + 2 * f.beacon_band),
                bottom_scale=1.0, top_scale=1.0, color=_color(BLOB_RGB[f"{goal}_beacon"])))
    return SceneEntity(timestamp=_ts(ns), frame_id="field", id="field", cubes=cubes,
                       cylinders=cylinders)


@dataclass
class Converter:
    """Stateful conversion (the subtask of the last action, the throttles)."""

    field_cfg: FieldConfig = field(default_factory=FieldConfig)
    image_every_ns: int = 200_000_000  # the drawn camera image: at most 5 Hz
    field_every_ns: int = 1_000_000_000  # the static field again (for late joiners)
    subtask: str = ""
    _image_ns: int = -(10**18)
    _field_ns: int = -(10**18)

    def convert(self, kind: str, msg: dict[str, Any], ns: int) -> list[tuple[str, Any]]:
        """Foxglove messages for one ROGER message of ``kind`` logged at ``ns``."""
        out: list[tuple[str, Any]] = []
        if ns - self._field_ns >= self.field_every_ns:
            self._field_ns = ns
            out.append(("/scene", SceneUpdate(entities=[field_entity(self.field_cfg, ns)])))
        handler = getattr(self, f"_{kind}", None)
        if handler is not None:
            out += handler(msg, ns)
        return out

    def _episode(self, m: dict[str, Any], ns: int) -> list[tuple[str, Any]]:
        data = m.get("data", {})
        out: list[tuple[str, Any]] = []
        if all(k in data for k in ("robot_x", "robot_y", "robot_yaw", "ball_x", "ball_y")):
            out += self._truth(data, ns)
        if m["event"] != "truth":
            text = f"episode {m['episode']}: {m['event']}" + "".join(
                f" {k}={v}" for k, v in data.items() if k in ("location", "location_name"))
            level = LogLevel.Warning if m["event"] in ("own_goal", "out", "timeout") else (
                LogLevel.Info)
            out.append(("/roger/events", Log(timestamp=_ts(ns), level=level, message=text,
                                             name=f"roger.sim.{m['robot']}")))
        return out

    def _truth(self, d: dict[str, Any], ns: int) -> list[tuple[str, Any]]:
        x, y, yaw = float(d["robot_x"]), float(d["robot_y"]), float(d["robot_yaw"])
        robot = SceneEntity(
            timestamp=_ts(ns), frame_id="field", id="robot",
            cubes=[_cube(x, y, 0.15, 0.28, 0.15, 0.12, (0.85, 0.85, 0.85), yaw),
                   _cube(x + 0.17 * math.cos(yaw), y + 0.17 * math.sin(yaw), 0.24, 0.09,
                         0.08, 0.08, (0.3, 0.3, 0.3), yaw)])
        ball = SceneEntity(
            timestamp=_ts(ns), frame_id="field", id="ball",
            spheres=[SpherePrimitive(pose=_pose(float(d["ball_x"]), float(d["ball_y"]), 0.042),
                                     size=Vector3(x=0.084, y=0.084, z=0.084),
                                     color=_color(BLOB_RGB["ball"]))])
        tf = FrameTransform(timestamp=_ts(ns), parent_frame_id="field", child_frame_id="robot",
                            translation=Vector3(x=x, y=y, z=0.0),
                            rotation=_yaw(yaw))
        return [("/scene", SceneUpdate(entities=[robot, ball])),
                ("/tf", FrameTransforms(transforms=[tf]))]

    def _perception(self, m: dict[str, Any], ns: int) -> list[tuple[str, Any]]:
        blobs = blobs_px(m["x"])
        circles, texts = [], []
        for name, (px, py, diameter) in blobs.items():
            rgb = BLOB_RGB[name]
            circles.append(CircleAnnotation(timestamp=_ts(ns), position=Point2(x=px, y=py),
                                            diameter=diameter, thickness=2.0,
                                            outline_color=_color(rgb),
                                            fill_color=_color(rgb, 0.3)))
            texts.append(TextAnnotation(timestamp=_ts(ns), position=Point2(x=px, y=py),
                                        text=name, font_size=10.0,
                                        text_color=_color((1, 1, 1))))
        out: list[tuple[str, Any]] = [
            ("/camera/blobs", ImageAnnotations(circles=circles, texts=texts))]
        if ns - self._image_ns >= self.image_every_ns:
            self._image_ns = ns
            out.append(("/camera/image", RawImage(
                timestamp=_ts(ns), frame_id="camera", width=CAMERA_W, height=CAMERA_H,
                encoding="rgb8", step=3 * CAMERA_W, data=draw_blobs(blobs).tobytes())))
        return out

    def _action(self, m: dict[str, Any], ns: int) -> list[tuple[str, Any]]:
        self.subtask = str(m.get("label", ""))
        return []

    def _command(self, m: dict[str, Any], ns: int) -> list[tuple[str, Any]]:
        return [("/roger/command", {"tick": m["tick"], "source": m["source"],
                                    "y": dict(zip(ACTION_NAMES, m["y"], strict=True))})]

    def _prediction(self, m: dict[str, Any], ns: int) -> list[tuple[str, Any]]:
        chosen = next((e for e in m["multimap"] if e["expert"] == m["expert"]), None)
        label = chosen["label"] if chosen else ""
        return [
            ("/roger/prediction", {
                "tick": m["tick"], "expert": m["expert"], "updates": m["updates"],
                "latency_ms": m["latency_ms"], "mode": m["mode"],
                "mean": dict(zip(ACTION_NAMES, m["mean"], strict=True)),
                "var": dict(zip(ACTION_NAMES, m["var"], strict=True)),
                "std": dict(zip(ACTION_NAMES, (math.sqrt(v) for v in m["var"]), strict=True)),
            }),
            ("/roger/expert", {"tick": m["tick"], "expert": m["expert"], "expert_label": label,
                               "subtask": self.subtask, "experts": len(m["multimap"])}),
        ]

    def _status(self, m: dict[str, Any], ns: int) -> list[tuple[str, Any]]:
        from roger_daemon.tools.status import describe, level_of

        level = LEVELS.get(level_of(m), LogLevel.Unknown)
        return [("/roger/status", Log(timestamp=_ts(ns), level=level, message=describe(m),
                                      name=f"roger.daemon.{m['daemon']}"))]


def blobs_px(x: list[float]) -> dict[str, tuple[float, float, float]]:
    """Seen blobs as (pixel x, pixel y, diameter in pixels) in the 208x160 camera image."""
    out = {}
    for i, name in enumerate(COLOURS):
        bx, by, size = x[3 * i: 3 * i + 3]
        if size < 0:
            continue
        px = (bx + 1.0) / 2.0 * CAMERA_W
        py = CAMERA_H / 2.0 - by * CAMERA_W / 2.0
        diameter = 2.0 * math.sqrt(size * size * CAMERA_W * CAMERA_H / math.pi)
        out[name] = (px, py, diameter)
    return out


def draw_blobs(blobs: dict[str, tuple[float, float, float]]) -> np.ndarray:
    """A grey 208x160 RGB image with each blob as a filled disc of its colour."""
    img = np.full((CAMERA_H, CAMERA_W, 3), 60, dtype=np.uint8)
    yy, xx = np.mgrid[0:CAMERA_H, 0:CAMERA_W]
    for name, (px, py, d) in sorted(blobs.items(), key=lambda kv: -kv[1][2]):
        mask = (xx - px) ** 2 + (yy - py) ** 2 <= (d / 2) ** 2
        img[mask] = [int(255 * c) for c in BLOB_RGB[name]]
    return img
