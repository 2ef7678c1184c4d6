"""Message types of the ROGER wire, encoded as msgpack maps.

Every message carries the header ``v`` (schema version), ``robot``, ``tick``, ``t`` (sim time in
seconds) and ``stamp_ns`` (the sender's wall clock, ns since the Unix epoch). The field tables
live in ``protocols/README.md``; this module is their executable form: the types and
``encode`` (:mod:`protocols.message_types`) and ``decode``, which validates type, dimensions,
finiteness and size and raises :class:`~protocols.errors.ProtocolError`
(:mod:`protocols.decoding`).
"""

from __future__ import annotations

from protocols.decoding import decode
from protocols.message_types import (
    CONTROL_OPS,
    EPISODE_EVENTS,
    MAX_MAP_ENTRIES,
    MAX_MULTIMAP,
    MAX_PAYLOAD_BYTES,
    MAX_STR,
    MAX_VECTOR,
    MODES,
    SCHEMA_VERSION,
    SOURCES,
    Action,
    Command,
    Control,
    Dims,
    EpisodeEvent,
    ExpertOutput,
    Message,
    Perception,
    Prediction,
    Status,
    encode,
    now_ns,
)
from protocols.prediction_bytes import encode_prediction, stamp_prediction

__all__ = [
    "CONTROL_OPS",
    "EPISODE_EVENTS",
    "MAX_MAP_ENTRIES",
    "MAX_MULTIMAP",
    "MAX_PAYLOAD_BYTES",
    "MAX_STR",
    "MAX_VECTOR",
    "MODES",
    "SCHEMA_VERSION",
    "SOURCES",
    "Action",
    "Command",
    "Control",
    "Dims",
    "EpisodeEvent",
    "ExpertOutput",
    "Message",
    "Perception",
    "Prediction",
    "Status",
    "decode",
    "encode",
    "encode_prediction",
    "now_ns",
    "stamp_prediction",
]
