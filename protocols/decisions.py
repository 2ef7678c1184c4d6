"""The daemon's decision records: what it learned, reset and dropped, and its model's digests.

These are not published on Zenoh: the daemon writes them into its session log (MCAP channels
``roger/<robot>/daemon/<event>``, :func:`protocols.keys.decision`), next to the messages it
received, so that replay and recovery read *what the daemon decided* instead of re-deriving it
from its inputs (``docs/durability.md``). They share the header of every ROGER message (``v``,
``robot``, ``tick``, ``t``, ``stamp_ns``: the daemon's wall clock when it decided) and are
msgpack maps like the wire's; the MCAP files' JSON Schemas are generated from these classes
too (``roger_daemon.recording.schemas``).

* ``learned``: the model learned a pair; ``updates`` is its ``n_learned`` after it, so the
  pair is model pair ``updates - 1``; ``x``, ``y`` and ``label`` are the pair itself;
* ``reset``: the model was replaced by a fresh one (``segment`` is the new segment number);
* ``dropped``: a completed pair was not learned (training queue full, or a re-sent copy);
* ``model``: a checkpoint's model digest (SHA-256 of its arrays, as
  ``roger_daemon.daemon.checkpoint.array_digest``) at ``updates``, chained with the previous one.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from typing import Any, ClassVar

from protocols.decoding import _header, _int, _str, _unpack, _vector
from protocols.errors import ProtocolError
from protocols.field_specs import spec
from protocols.message_types import Dims, FloatArray, Message, as_vector

__all__ = [
    "DECISION_TYPES",
    "DROP_REASONS",
    "Dropped",
    "Learned",
    "ModelDigest",
    "Reset",
    "chain_digest",
    "decode_decision",
]

DROP_REASONS = ("queue_full", "resent")
_HEX64 = "^[0-9a-f]{64}$"


def chain_digest(previous: str, digest: str) -> str:
    """The next link of a digest chain: SHA-256 (hex) of ``previous`` then ``digest``."""
    return hashlib.sha256(f"{previous}{digest}".encode()).hexdigest()


@dataclass(frozen=True, eq=False)
class Learned(Message):
    """The model learned the pair ``(x, y)`` of ``tick``, as its pair number ``updates - 1``."""

    updates: int = field(metadata=spec("the model's n_learned after learning this pair"))
    segment: int = field(metadata=spec("resets before this pair in the session"))
    x: FloatArray = field(metadata=spec("the perception learned, Dims.x floats"))
    y: FloatArray = field(metadata=spec("the action learned, Dims.y floats"))
    label: str = field(default="", metadata=spec("the action's subtask label"))

    KIND: ClassVar[str] = "daemon.learned"
    DESCRIPTION: ClassVar[str] = (
        "The daemon's model learned this pair (perception x and action y of `tick`).")

    def __post_init__(self) -> None:
        object.__setattr__(self, "x", as_vector(self.x))
        object.__setattr__(self, "y", as_vector(self.y))

    def body(self) -> dict[str, Any]:
        """The record's own fields as a msgpack-ready map."""
        return {"updates": int(self.updates), "segment": int(self.segment),
                "x": self.x.tolist(), "y": self.y.tolist(), "label": self.label}


@dataclass(frozen=True, eq=False)
class Reset(Message):
    """The model was replaced by a fresh one (a ``reset`` control)."""

    segment: int = field(metadata=spec("the new segment: resets so far in the session"))
    forgotten: int = field(metadata=spec("pairs the replaced model had learned"))

    KIND: ClassVar[str] = "daemon.reset"
    DESCRIPTION: ClassVar[str] = "The daemon replaced the robot's model by a fresh one."

    def body(self) -> dict[str, Any]:
        """The record's own fields as a msgpack-ready map."""
        return {"segment": int(self.segment), "forgotten": int(self.forgotten)}


@dataclass(frozen=True, eq=False)
class Dropped(Message):
    """The completed pair of ``tick`` was not learned."""

    reason: str = field(metadata=spec("why the pair was not learned", choices=DROP_REASONS))
    queue_size: int = field(metadata=spec("the training queue's capacity"))
    dropped: int = field(metadata=spec("the robot's drop counter after this drop"))

    KIND: ClassVar[str] = "daemon.dropped"
    DESCRIPTION: ClassVar[str] = (
        "A completed training pair the daemon did not learn: its training queue was full, or "
        "it was a re-sent copy of the newest pair.")

    def body(self) -> dict[str, Any]:
        """The record's own fields as a msgpack-ready map."""
        return {"reason": self.reason, "queue_size": int(self.queue_size),
                "dropped": int(self.dropped)}


@dataclass(frozen=True, eq=False)
class ModelDigest(Message):
    """The digest of the model a checkpoint saved, and the session's chain of digests."""

    updates: int = field(metadata=spec("the model's n_learned"))
    segment: int = field(metadata=spec("resets before this model in the session"))
    digest: str = field(metadata=spec("SHA-256 of the model's arrays (hex)", pattern=_HEX64))
    chain: str = field(metadata=spec(
        "SHA-256 of the previous record's chain (the first: the session's start_model_digest) "
        "and this digest (hex)",
        pattern=_HEX64))

    KIND: ClassVar[str] = "daemon.model"
    DESCRIPTION: ClassVar[str] = (
        "The digest of the model a checkpoint saved, chained with the session's previous one.")

    def body(self) -> dict[str, Any]:
        """The record's own fields as a msgpack-ready map."""
        return {"updates": int(self.updates), "segment": int(self.segment),
                "digest": self.digest, "chain": self.chain}


#: event name (the last part of ``roger/<robot>/daemon/<event>``) -> record class
DECISION_TYPES: dict[str, type[Message]] = {
    cls.KIND.split(".")[1]: cls for cls in (Learned, Reset, Dropped, ModelDigest)
}


def _hex64(m: dict[Any, Any], name: str, kind: str) -> str:
    v = _str(m, name, kind)
    if len(v) != 64 or any(c not in "0123456789abcdef" for c in v):
        raise ProtocolError("bad_value", f"{kind}: {name!r} must be 64 hex digits")
    return v


def decode_decision(event: str, payload: bytes, *, dims: Dims | None = None,
                    robot: str | None = None) -> Message:
    """Decode and validate one decision record of ``event`` (a key of :data:`DECISION_TYPES`);
    ``ProtocolError`` if it is not one."""
    cls = DECISION_TYPES.get(event)
    if cls is None:
        raise ProtocolError("bad_key", f"unknown decision record {event!r}")
    kind = cls.KIND
    m = _unpack(kind, payload, 1 << 20)
    head = _header(kind, m, robot)
    if cls is Learned:
        return Learned(**head, updates=_int(m, "updates", kind, lo=1),
                       segment=_int(m, "segment", kind, lo=0),
                       x=_vector(m, "x", kind, dims.x if dims else None),
                       y=_vector(m, "y", kind, dims.y if dims else None),
                       label=_str(m, "label", kind))
    if cls is Reset:
        return Reset(**head, segment=_int(m, "segment", kind, lo=0),
                     forgotten=_int(m, "forgotten", kind, lo=0))
    if cls is Dropped:
        return Dropped(**head, reason=_str(m, "reason", kind, choices=DROP_REASONS),
                       queue_size=_int(m, "queue_size", kind, lo=0),
                       dropped=_int(m, "dropped", kind, lo=0))
    return ModelDigest(**head, updates=_int(m, "updates", kind, lo=0),
                       segment=_int(m, "segment", kind, lo=0),
                       digest=_hex64(m, "digest", kind), chain=_hex64(m, "chain", kind))
