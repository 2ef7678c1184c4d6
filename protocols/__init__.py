"""The ROGER wire: key expressions and msgpack message types shared by every process."""

from __future__ import annotations

from protocols import keys
from protocols.errors import ProtocolError
from protocols.messages import (
    SCHEMA_VERSION,
    Action,
    Command,
    Control,
    Dims,
    EpisodeEvent,
    ExpertOutput,
    Perception,
    Prediction,
    Status,
    decode,
    encode,
)

__all__ = [
    "SCHEMA_VERSION",
    "Action",
    "Command",
    "Control",
    "Dims",
    "EpisodeEvent",
    "ExpertOutput",
    "Perception",
    "Prediction",
    "ProtocolError",
    "Status",
    "decode",
    "encode",
    "keys",
]
