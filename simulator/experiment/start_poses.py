"""``--start-poses FILE``: evaluation from start poses the demonstrations never used.

The file (TOML or JSON, chosen by its suffix; ``docs/goal-scoring.md``) lists poses, each a
robot pose and a ball position on the field, in the frame of ``simulator.episodes``
(metres from the centre spot, x towards the opponent goal, heading in degrees, 0 faces the
opponent goal)::

    [[pose]]                       # TOML          {"pose": [                       JSON
    name = "corner"                                  {"name": "corner",
    robot = [1.8, -1.2, 135.0]                        "robot": [1.8, -1.2, 135.0],
    ball = [1.5, -0.9]                                "ball": [1.5, -0.9]}]}

``name`` is optional. Each pose is seeded like a start location whose index is its position in
the file (the same start noise as the demonstrations). A bad file raises
:class:`StartPoseError` naming the entry and field, the expected form and the value given.
"""

from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path
from typing import Any

from simulator.episodes import StartLocation

__all__ = ["StartPoseError", "evaluate_held_out", "load_start_poses", "parse_start_poses"]

#: The ball must be at least this far (m) from the robot's centre (not inside its body).
MIN_BALL_DISTANCE = 0.15


class StartPoseError(ValueError):
    """A ``--start-poses`` file is unreadable or an entry is malformed."""


def _numbers(where: str, value: object, n: int, form: str) -> tuple[float, ...]:
    if not isinstance(value, list | tuple) or len(value) != n or not all(
            isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
            for v in value):
        raise StartPoseError(f"{where}: expected {form}, got {value!r}")
    return tuple(float(v) for v in value)


def _inside(where: str, xy: tuple[float, float], half: tuple[float, float]) -> None:
    if abs(xy[0]) >= half[0] or abs(xy[1]) >= half[1]:
        raise StartPoseError(f"{where}: expected a point inside the field (|x| < {half[0]:g}, "
                             f"|y| < {half[1]:g} m), got {list(xy)}")


def parse_start_poses(data: Any, source: str = "start poses",
                      field_size: tuple[float, float] = (5.4, 3.6)) -> list[StartLocation]:
    """Validate the decoded file (a ``{"pose": [...]}`` table) into start locations."""
    if not isinstance(data, dict) or "pose" not in data:
        got = f"keys {sorted(data)}" if isinstance(data, dict) else type(data).__name__
        raise StartPoseError(f"{source}: expected a table with a 'pose' array of entries "
                             f"(see docs/goal-scoring.md), got {got}")
    entries = data["pose"]
    if not isinstance(entries, list) or not entries:
        raise StartPoseError(f"{source}: 'pose' must be a non-empty array of tables, got "
                             f"{entries!r}")
    half = (field_size[0] / 2, field_size[1] / 2)
    out = []
    for i, e in enumerate(entries):
        where = f"{source}: pose[{i}]"
        if not isinstance(e, dict):
            raise StartPoseError(f"{where}: expected a table with robot and ball, got {e!r}")
        unknown = sorted(set(e) - {"name", "robot", "ball"})
        if unknown:
            raise StartPoseError(f"{where}: unknown key(s) {unknown}; expected name, robot, "
                                 "ball")
        for key in ("robot", "ball"):
            if key not in e:
                raise StartPoseError(f"{where}: missing '{key}'")
        robot = _numbers(f"{where}.robot", e["robot"], 3, "[x m, y m, heading deg]")
        ball = _numbers(f"{where}.ball", e["ball"], 2, "[x m, y m]")
        _inside(f"{where}.robot", (robot[0], robot[1]), half)
        _inside(f"{where}.ball", (ball[0], ball[1]), half)
        d = math.dist(robot[:2], ball)
        if d < MIN_BALL_DISTANCE:
            raise StartPoseError(f"{where}.ball: expected at least {MIN_BALL_DISTANCE} m from "
                                 f"the robot, got {d:.3f} m ({list(ball)})")
        name = e.get("name", f"pose-{i}")
        if not isinstance(name, str):
            raise StartPoseError(f"{where}.name: expected a string, got {name!r}")
        out.append(StartLocation(i, name, (robot[0], robot[1], robot[2]), (ball[0], ball[1]),
                                 "from " + source))
    return out


def load_start_poses(path: str | Path, field_size: tuple[float, float] = (5.4, 3.6)
                     ) -> list[StartLocation]:
    """Read and validate a TOML (``.toml``) or JSON (``.json``) start-pose file."""
    p = Path(path)
    if p.suffix not in (".toml", ".json"):
        raise StartPoseError(f"--start-poses {p}: expected a .toml or .json file, got suffix "
                             f"{p.suffix!r}")
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise StartPoseError(f"--start-poses {p}: cannot read: {exc.strerror or exc}") from None
    try:
        data = tomllib.loads(text) if p.suffix == ".toml" else json.loads(text)
    except (tomllib.TOMLDecodeError, json.JSONDecodeError) as exc:
        raise StartPoseError(f"--start-poses {p}: not valid {p.suffix[1:].upper()}: {exc}"
                             ) from None
    return parse_start_poses(data, str(p), field_size)


def evaluate_held_out(plan: Any, context: dict[str, Any], starts: list[StartLocation]
                      ) -> dict[str, Any]:
    """HCC, segmentation oracle, every ROGER model, its merged groups and its learned
    transitions from ``starts`` (in-process)."""
    from dataclasses import replace

    from simulator.experiment.pipeline import controllers_for, evaluate_in_process

    locs = list(range(len(starts)))
    sub = replace(plan, controllers=tuple(c for c in plan.controllers if c != "dpa"))
    ctl = controllers_for(sub, context["stream"], context["models"], None,
                          context.get("oracle"), context.get("merged", []),
                          context.get("fsms", []))
    episodes = evaluate_in_process(sub, ctl, locations=locs, starts=starts)
    return held_out_block(plan, starts, episodes)


def held_out_block(plan: Any, starts: list[StartLocation],
                   episodes: dict[str, list[dict[str, Any]]]) -> dict[str, Any]:
    """``results.json``'s ``held_out``: the poses, every controller's block (pooled over
    learner seeds, and per seed) and its ratio to the HCC."""
    from simulator.experiment.report import controller_block

    out: dict[str, Any] = {
        "file": plan.start_poses,
        "poses": [{"name": s.name, "robot": list(s.robot), "ball": list(s.ball)}
                  for s in starts],
        "attempts": plan.attempts,
        "episodes": episodes,
    }
    for key in ("hcc", "oracle"):
        if key in episodes:
            out[key] = controller_block(episodes[key])
    for c in ("roger", "groups", "autonomous"):
        pooled = [e for k, eps in episodes.items() if k.startswith(f"{c}:") for e in eps]
        if pooled:
            out[c] = controller_block(pooled)
            out[f"{c}_seeds"] = [controller_block(eps) for k, eps in sorted(episodes.items())
                                 if k.startswith(f"{c}:")]
    hcc = out.get("hcc", {}).get("success_rate")
    for key in ("roger", "oracle", "groups", "autonomous"):
        rate = out.get(key, {}).get("success_rate")
        out[f"ratio_{key}_to_hcc"] = rate / hcc if hcc and rate is not None else None
    return out
