"""Named fields: a log message's vectors as ``{name: value}`` maps, by the robot's profile.

The wire carries vectors (``x[23]``, ``y[9]``); a reader of an exported log wants
``ball_x``. :func:`named_fields` maps each vector field of a message kind onto the names of
the robot's profile (:mod:`roger_daemon.profiles`: the one the log's metadata records, else the
shipped profile of those dimensions, else ``x0 ..`` / ``y0 ..``). ``roger log export --format
json`` adds the result to every message as ``named`` (the vectors themselves stay), and
:func:`with_named_schema` adds it to the message's JSON Schema, so a Foxglove plot can use
``/roger/aibo/perception.named.x.ball_x``.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

from protocols import keys
from protocols.errors import ProtocolError
from roger_daemon.profiles import RobotProfile

__all__ = ["VECTOR_FIELDS", "kind_of", "named_fields", "with_named_schema"]

#: message kind -> {vector field: which names ("x": perception, "y": action)}
VECTOR_FIELDS: Mapping[str, Mapping[str, str]] = {
    "perception": {"x": "x"},
    "action": {"y": "y"},
    "command": {"y": "y"},
    "prediction": {"mean": "y", "var": "y"},
    "daemon.learned": {"x": "x", "y": "y"},
}


def kind_of(topic: str) -> str | None:
    """The message kind of a ROGER topic (``roger/<robot>/<kind>`` or a decision channel)."""
    decision = keys.parse_decision(topic)
    if decision is not None:
        return f"daemon.{decision[1]}"
    try:
        return keys.parse(topic)[1]
    except ProtocolError:
        return None


def named_fields(kind: str | None, value: Any, profile: RobotProfile
                 ) -> dict[str, dict[str, float]] | None:
    """``{field: {name: value}}`` of the vector fields of one decoded message (``None`` if
    the kind has none, or a vector's length is not the profile's)."""
    fields = VECTOR_FIELDS.get(kind or "")
    if not fields or not isinstance(value, dict):
        return None
    out: dict[str, dict[str, float]] = {}
    for name, axis in fields.items():
        vec = value.get(name)
        names = profile.x_names if axis == "x" else profile.y_names
        if not isinstance(vec, list) or len(vec) != len(names):
            return None
        out[name] = dict(zip(names, vec, strict=True))
    return out


def with_named_schema(schema_data: bytes, kind: str | None, profile: RobotProfile) -> bytes:
    """A message kind's JSON Schema with the optional ``named`` object added."""
    fields = VECTOR_FIELDS.get(kind or "")
    if not fields:
        return schema_data
    doc = json.loads(schema_data)
    props = {}
    for name, axis in fields.items():
        names = profile.x_names if axis == "x" else profile.y_names
        props[name] = {"type": "object", "description": f"{name} by {axis} name",
                       "properties": {n: {"type": ["number", "null"]} for n in names}}
    doc.setdefault("properties", {})["named"] = {
        "type": "object", "properties": props,
        "description": f"the vectors by the names of robot profile {profile.name or '(none)'}"}
    return json.dumps(doc, sort_keys=True, separators=(",", ":")).encode()
