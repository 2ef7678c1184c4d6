"""Daemon-internal events written to the session log (never published on Zenoh).

So far one: ``dropped``. When the daemon's training queue is full, a completed pair is
dropped (``RobotRuntime._enqueue``); the log's perception and action alone cannot say which
pair that was, so the daemon writes one small record on the channel
``roger/<robot>/daemon/dropped`` right after the message that completed the pair. Replay and
log-tail catch-up remove that pair, so replays stay exact when the queue overflows.

The payload is msgpack, like every other channel, with the jsonschema
:func:`dropped_schema` (name ``roger.daemon.dropped``)::

    {"v": 1, "robot": "aibo", "tick": 4711, "stamp_ns": ..., "reason": "queue_full",
     "queue_size": 256, "dropped": 3}

``dropped`` is the robot's running drop counter after this drop.
"""

from __future__ import annotations

import json
import re
from typing import Any

import msgpack

__all__ = [
    "DROPPED_SCHEMA_NAME",
    "EVENT_VERSION",
    "decode_dropped",
    "dropped_schema",
    "dropped_schema_bytes",
    "dropped_topic",
    "encode_dropped",
    "parse_event_topic",
]

EVENT_VERSION = 1
DROPPED_SCHEMA_NAME = "roger.daemon.dropped"
_TOPIC = re.compile(r"^roger/(?P<robot>[A-Za-z0-9_\-]{1,64})/daemon/(?P<event>[a-z_]{1,32})$")


def dropped_topic(robot: str) -> str:
    """``roger/<robot>/daemon/dropped``: the log channel of queue drops."""
    return f"roger/{robot}/daemon/dropped"


def parse_event_topic(topic: str) -> tuple[str, str] | None:
    """``(robot, event)`` of a daemon-event topic, or None if ``topic`` is not one."""
    m = _TOPIC.match(topic)
    return (m["robot"], m["event"]) if m else None


def encode_dropped(robot: str, tick: int, *, stamp_ns: int, queue_size: int,
                   dropped: int, reason: str = "queue_full") -> bytes:
    """The payload of one drop record (``reason``: ``queue_full`` or ``resent``, a re-sent
    copy of the newest pair)."""
    out: bytes = msgpack.packb({
        "v": EVENT_VERSION, "robot": robot, "tick": int(tick), "stamp_ns": int(stamp_ns),
        "reason": reason, "queue_size": int(queue_size), "dropped": int(dropped),
    })
    return out


def decode_dropped(payload: bytes) -> int:
    """The tick of a drop record; ``ValueError`` if the payload is not one."""
    try:
        m: Any = msgpack.unpackb(payload, raw=False, strict_map_key=False)
    except Exception as exc:
        raise ValueError(f"drop record is not msgpack ({exc})") from None
    tick = m.get("tick") if isinstance(m, dict) else None
    if isinstance(tick, bool) or not isinstance(tick, int) or tick < 0:
        raise ValueError(f"drop record without a valid tick: {m!r:.80}")
    return tick


def dropped_schema() -> dict[str, Any]:
    """The JSON Schema of a drop record."""
    def num(kind: str, desc: str) -> dict[str, Any]:
        return {"type": kind, "minimum": 0, "description": desc}

    props = {
        "v": {"const": EVENT_VERSION, "description": "version of the daemon event records"},
        "robot": {"type": "string", "pattern": "^[A-Za-z0-9_\\-]{1,64}$",
                  "description": "robot id"},
        "tick": num("integer", "tick of the pair the daemon dropped (its perception and "
                    "action are the messages just before this record)"),
        "stamp_ns": num("integer", "daemon wall clock, ns since the Unix epoch"),
        "reason": {"type": "string", "enum": ["queue_full", "resent"],
                   "description": "why the pair was not learned"},
        "queue_size": num("integer", "the training queue's capacity"),
        "dropped": num("integer", "the robot's drop counter after this drop"),
    }
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "$id": f"urn:roger:schema:daemon.dropped:v{EVENT_VERSION}",
        "title": DROPPED_SCHEMA_NAME,
        "description": "A completed training pair the daemon dropped because its training queue "
                       "was full (never learned).",
        "type": "object",
        "properties": props,
        "required": list(props),
        "additionalProperties": False,
    }


def dropped_schema_bytes() -> bytes:
    """The schema as compact, key-sorted UTF-8 JSON."""
    return json.dumps(dropped_schema(), sort_keys=True, separators=(",", ":")).encode()
