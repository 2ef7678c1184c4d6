"""Read a Foxglove MCAP back, and draw its ``/scene`` channel from above as a PNG.

:func:`read_messages` decodes every message of a Foxglove MCAP (``roger view --record`` or
``--log ... --out``) into plain dicts: JSON channels with ``json``, protobuf channels with the
schema the file carries (its FileDescriptorSet, through ``google.protobuf``). :func:`render_scene`
draws the last field entity, the robot's and the ball's paths and their last poses from the
``foxglove.SceneUpdate`` messages, so the picture shows what the 3D panel shows; the paths are
cut where an episode starts (``episode N: start`` on ``/roger/events``), so that the robot's
jump back to a start pose is not drawn as a line across the field::

    python -m simulator.view.render SESSION.foxglove.mcap --out docs/figures/live_scene.png
"""

from __future__ import annotations

import argparse
import json
import math
import re
from pathlib import Path
from typing import Any

__all__ = ["episode_paths", "read_messages", "render_scene"]

#: an episode's start on /roger/events (simulator.view.scene: "episode N: start ...")
_START = re.compile(r"^episode \S+: start\b")


def _protobuf_class(schema: Any) -> Any:
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    fds = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
    pool = descriptor_pool.DescriptorPool()
    for fd in fds.file:
        pool.Add(fd)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))


def read_messages(
    path: Path, topics: set[str] | None = None
) -> list[tuple[str, int, dict[str, Any]]]:
    """``(topic, log_time_ns, message as a dict)`` for every message (of ``topics``)."""
    from google.protobuf.json_format import MessageToDict
    from mcap.reader import make_reader

    classes: dict[int, Any] = {}
    out = []
    with path.open("rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages(log_time_order=True):
            if topics is not None and channel.topic not in topics:
                continue
            if channel.message_encoding == "json":
                out.append((channel.topic, message.log_time, json.loads(message.data)))
                continue
            if schema is None or schema.encoding != "protobuf":
                continue
            if schema.id not in classes:
                classes[schema.id] = _protobuf_class(schema)
            msg = classes[schema.id].FromString(message.data)
            out.append((channel.topic, message.log_time,
                        MessageToDict(msg, preserving_proto_field_name=True)))
    return out


def _xyz(pose: dict[str, Any]) -> tuple[float, float, float]:
    p = pose.get("position", {})
    return float(p.get("x", 0.0)), float(p.get("y", 0.0)), float(p.get("z", 0.0))


def _yaw(pose: dict[str, Any]) -> float:
    q = pose.get("orientation", {})
    return 2.0 * math.atan2(float(q.get("z", 0.0)), float(q.get("w", 1.0)))


def _rgb(c: dict[str, Any]) -> tuple[float, float, float]:
    return float(c.get("r", 0.0)), float(c.get("g", 0.0)), float(c.get("b", 0.0))


def _tracks(path: Path) -> tuple[dict[str, Any] | None, list[tuple[float, float, float]],
                                 list[tuple[float, float]], list[tuple[int, int]]]:
    """The last field entity, the robot's poses, the ball's positions, and where (in both)
    each episode starts."""
    field: dict[str, Any] | None = None
    robot: list[tuple[float, float, float]] = []
    ball: list[tuple[float, float]] = []
    cuts: list[tuple[int, int]] = []  # (robot poses, ball positions) where an episode starts
    for topic, _, upd in read_messages(path, {"/scene", "/roger/events"}):
        if topic == "/roger/events":
            if _START.match(str(upd.get("message", ""))):
                cuts.append((len(robot), len(ball)))
            continue
        for ent in upd.get("entities", []):
            if ent.get("id") == "field":
                field = ent
            elif ent.get("id") == "robot" and ent.get("cubes"):
                x, y, _ = _xyz(ent["cubes"][0]["pose"])
                robot.append((x, y, _yaw(ent["cubes"][0]["pose"])))
            elif ent.get("id") == "ball" and ent.get("spheres"):
                x, y, _ = _xyz(ent["spheres"][0]["pose"])
                ball.append((x, y))
    return field, robot, ball, cuts


def render_scene(path: Path, out: Path, title: str = "") -> dict[str, int]:
    """Draw the ``/scene`` channel of ``path`` into ``out`` (PNG); counts of what was drawn."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, Rectangle
    from matplotlib.transforms import Affine2D

    field, robot, ball, cuts = _tracks(path)
    if field is None:
        raise ValueError(f"{path}: no field entity on /scene (is it a roger view file?)")
    fig, ax = plt.subplots(figsize=(7.5, 5.2), dpi=110)
    for cube in field.get("cubes", []):
        x, y, _ = _xyz(cube["pose"])
        sx, sy = float(cube["size"].get("x", 0)), float(cube["size"].get("y", 0))
        ax.add_patch(Rectangle((x - sx / 2, y - sy / 2), sx, sy, color=_rgb(cube["color"])))
    for cyl in field.get("cylinders", []):
        x, y, _ = _xyz(cyl["pose"])
        ax.add_patch(Circle((x, y), float(cyl["size"].get("x", 0.1)),
                            color=_rgb(cyl["color"]), ec="k", lw=0.5))
    for i, part in enumerate(_pieces([(x, y) for x, y in ball], [c[1] for c in cuts])):
        ax.plot(*zip(*part, strict=True), color=(1.0, 0.5, 0.0), lw=1.5,
                label="ball" if i == 0 else None)
    if ball:
        ax.add_patch(Circle(ball[-1], 0.06, color=(1.0, 0.5, 0.0), ec="k", lw=0.5))
    paths = _pieces([(x, y) for x, y, _ in robot], [c[0] for c in cuts])
    for i, part in enumerate(paths):
        ax.plot(*zip(*part, strict=True), color="white", lw=1.5,
                label="robot" if i == 0 else None)
    if robot:
        x, y, yaw = robot[-1]
        body = Rectangle((x - 0.14, y - 0.075), 0.28, 0.15, color=(0.85, 0.85, 0.85), ec="k",
                         transform=Affine2D().rotate_around(x, y, yaw) + ax.transData)
        ax.add_patch(body)
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_xlabel("x (m), towards the attacked goal")
    ax.set_ylabel("y (m)")
    ax.set_title(title or f"/scene of {path.name}: {len(robot)} robot poses")
    if robot or ball:
        ax.legend(loc="upper left", fontsize=8, facecolor=(0.1, 0.4, 0.15), labelcolor="white")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    plt.close(fig)
    return {"robot_poses": len(robot), "ball_positions": len(ball)}


def episode_paths(path: Path) -> dict[str, list[list[tuple[float, float]]]]:
    """The robot's and the ball's paths on ``/scene``, one per episode: what is drawn."""
    _, robot, ball, cuts = _tracks(path)
    return {"robot": _pieces([(x, y) for x, y, _ in robot], [c[0] for c in cuts]),
            "ball": _pieces(ball, [c[1] for c in cuts])}


def _pieces(points: list[tuple[float, float]], cuts: list[int]
            ) -> list[list[tuple[float, float]]]:
    """``points`` cut before each index of ``cuts`` (empty pieces left out).

    >>> _pieces([(0, 0), (1, 1), (5, 5), (6, 6)], [0, 2])
    [[(0, 0), (1, 1)], [(5, 5), (6, 6)]]
    """
    bounds = sorted({0, *cuts, len(points)})
    return [points[a:b] for a, b in zip(bounds, bounds[1:], strict=False) if b > a]


def main(argv: list[str] | None = None) -> int:
    """``python -m simulator.view.render FILE --out PNG``."""
    parser = argparse.ArgumentParser(prog="python -m simulator.view.render",
                                     description="draw the /scene channel of a roger view MCAP")
    parser.add_argument("file", type=Path, help="a Foxglove MCAP written by roger view")
    parser.add_argument("--out", type=Path, required=True, help="the PNG to write")
    parser.add_argument("--title", default="", help="the figure's title")
    args = parser.parse_args(argv)
    counts = render_scene(args.file, args.out, args.title)
    print(f"wrote {args.out}: {counts}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
