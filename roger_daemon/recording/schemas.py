"""JSON Schemas (draft 2020-12) of the ROGER messages, one per kind.

These are the documentation schemas registered in every MCAP file (schema encoding
``jsonschema``, schema name ``roger.<kind>``). The channels themselves carry msgpack, which has
the same data model as JSON for these messages (maps with string keys, arrays, numbers, strings),
so the same schema describes the msgpack payload and the JSON that ``roger log export`` writes.

The field lists are the executable ones of :mod:`protocols.messages` (``Message.to_map``); a test
checks that every kind's ``properties`` are exactly the keys that ``to_map`` produces and that
encoded messages validate.
"""

from __future__ import annotations

import json
from typing import Any

from protocols.keys import KINDS
from protocols.messages import (
    CONTROL_OPS,
    EPISODE_EVENTS,
    MAX_MULTIMAP,
    MAX_STR,
    MAX_VECTOR,
    MODES,
    SCHEMA_VERSION,
)

__all__ = ["SCHEMA_ENCODING", "SCHEMA_PREFIX", "schema", "schema_bytes", "schema_name"]

SCHEMA_ENCODING = "jsonschema"
SCHEMA_PREFIX = "roger."
_DRAFT = "https://json-schema.org/draft/2020-12/schema"


def _num(desc: str) -> dict[str, Any]:
    return {"type": "number", "description": desc}


def _int(desc: str, minimum: int | None = 0) -> dict[str, Any]:
    out: dict[str, Any] = {"type": "integer", "description": desc}
    if minimum is not None:
        out["minimum"] = minimum
    return out


def _str(desc: str, enum: tuple[str, ...] = ()) -> dict[str, Any]:
    out: dict[str, Any] = {"type": "string", "maxLength": MAX_STR, "description": desc}
    if enum:
        out["enum"] = list(enum)
    return out


def _vec(desc: str, *, positive: bool = False) -> dict[str, Any]:
    item: dict[str, Any] = {"type": "number"}
    if positive:
        item["exclusiveMinimum"] = 0
    return {"type": "array", "items": item, "maxItems": MAX_VECTOR, "description": desc}


def _obj(desc: str) -> dict[str, Any]:
    return {"type": "object", "description": desc}


_HEADER: dict[str, dict[str, Any]] = {
    "v": {"const": SCHEMA_VERSION, "description": "schema version of the ROGER wire"},
    "robot": {
        "type": "string",
        "pattern": "^[A-Za-z0-9_\\-]{1,64}$",
        "description": "robot id, the same as in the key expression roger/<robot>/<kind>",
    },
    "tick": _int("control tick the message belongs to (the MCAP sequence field)"),
    "t": _num("simulation (or robot) time in seconds"),
    "stamp_ns": _int("sender's wall clock, ns since the Unix epoch (the MCAP publish_time)"),
}

_EXPERT: dict[str, Any] = {
    "type": "object",
    "description": "one expert of the MAP particle, as seen from the query perception",
    "properties": {
        "expert": _int("expert id, unique over the life of the model", minimum=-1),
        "p": _num("gate probability of this expert for the query perception"),
        "mean": _vec("predictive mean of this expert (action units)"),
        "var": _vec("predictive variance of this expert, > 0", positive=True),
        "n": _int("training points assigned to this expert"),
        "label": _str("majority subtask label of the expert's points ('' if none)"),
    },
    "required": ["expert", "p", "mean", "var", "n", "label"],
    "additionalProperties": False,
}

_BODIES: dict[str, tuple[str, dict[str, dict[str, Any]]]] = {
    "perception": (
        "What the robot senses at `tick` (23 floats for the AIBO; see protocols/aibo.py).",
        {"x": _vec("perception vector, Dims.x floats")},
    ),
    "action": (
        "The demonstrator's action for the perception of the same tick, with its subtask label "
        "(evaluation only; never enters the learner).",
        {
            "y": _vec("action vector, Dims.y floats"),
            "label": _str("the demonstrator's subtask label"),
        },
    ),
    "command": (
        "What the robot is told to do at `tick`.",
        {
            "y": _vec("command vector, Dims.y floats"),
            "source": _str("the controller that produced it"),
        },
    ),
    "prediction": (
        "The learner's answer for the perception of `tick`.",
        {
            "mean": _vec("chosen expert's predictive mean (action units)"),
            "var": _vec("chosen expert's predictive variance, > 0", positive=True),
            "expert": _int("chosen expert id, -1 before any learning", minimum=-1),
            "multimap": {
                "type": "array",
                "items": _EXPERT,
                "maxItems": MAX_MULTIMAP,
                "description": "every expert of the MAP particle",
            },
            "latency_ms": _num("from perception receipt to publish, ms"),
            "mode": _str("daemon mode", MODES),
            "updates": _int(
                "training pairs the model had learned when it computed this prediction"
            ),
        },
    ),
    "episode": (
        "An episode event from the simulator.",
        {
            "event": _str("what happened", EPISODE_EVENTS),
            "episode": _int("episode number"),
            "data": _obj("small named values (pose, location, ...)"),
        },
    ),
    "status": (
        "Daemon health for one robot, 1 Hz.",
        {
            "daemon": _str("daemon id"),
            "mode": _str("daemon mode", MODES),
            "ticks": _int("loop ticks so far"),
            "updates": _int("training pairs learned so far"),
            "updates_per_s": _num("learning rate, pairs per second"),
            "experts": _int("experts in the MAP particle"),
            "queue_depth": _int("messages waiting in the daemon's queues"),
            "dropped": _int("messages dropped so far"),
            "invalid": {
                "type": "object",
                "additionalProperties": {"type": "integer"},
                "description": "invalid messages by ProtocolError reason",
            },
            "latency_ms_p50": _num("median prediction latency, ms"),
            "latency_ms_p99": _num("99th percentile prediction latency, ms"),
            "uptime_s": _num("seconds since the daemon started"),
            "info": _obj("free-form extra health values"),
        },
    ),
    "control": (
        "A request to the daemon: op 'mode' (with mode), 'reset' or 'checkpoint'.",
        {
            "op": _str("the request", CONTROL_OPS),
            "mode": _str("the new mode for op 'mode', else ''"),
        },
    ),
}

assert set(_BODIES) == set(KINDS)


def schema_name(kind: str) -> str:
    """``roger.<kind>``: the MCAP schema name of a message kind."""
    return SCHEMA_PREFIX + kind


def schema(kind: str) -> dict[str, Any]:
    """The JSON Schema of one message kind (a fresh dict)."""
    if kind not in _BODIES:
        raise KeyError(f"no schema for message kind {kind!r}; kinds are {KINDS}")
    desc, body = _BODIES[kind]
    props = {**_HEADER, **body}
    return {
        "$schema": _DRAFT,
        "$id": f"urn:roger:schema:{kind}:v{SCHEMA_VERSION}",
        "title": schema_name(kind),
        "description": desc,
        "type": "object",
        "properties": json.loads(json.dumps(props)),
        "required": list(props),
        "additionalProperties": False,
    }


def schema_bytes(kind: str) -> bytes:
    """The schema as compact, key-sorted UTF-8 JSON (what goes into the MCAP Schema record)."""
    return json.dumps(schema(kind), sort_keys=True, separators=(",", ":")).encode()
