"""``roger log export FILE --format json --out OUT.mcap``: the session as JSON, for Foxglove.

The output is an MCAP file whose channels have message encoding ``json`` and the
``jsonschema`` schemas of the msgpack log (Foxglove opens json + jsonschema natively; msgpack
is not in its list). Topics, log time, publish time, sequence and the metadata records are
kept. Every message with vectors also gets them by name, ``named`` (``{"x": {"ball_x": ...}}``,
:mod:`roger_daemon.recording.named`; its schema says so). Binary values (none in the ROGER
messages) become base64 strings; a payload that is not msgpack is skipped and counted.
The msgpack log is left as it is: replay reads its bytes, never a re-encoding.
"""

from __future__ import annotations

import base64
import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import msgpack
from mcap.records import Channel, Message, Metadata, Schema
from mcap.well_known import MessageEncoding
from mcap.writer import CompressionType, Writer

from roger_daemon.atomic import atomic_write
from roger_daemon.recording.mcapio import LogReader, read_metadata
from roger_daemon.recording.metadata import SessionInfo
from roger_daemon.recording.named import kind_of, named_fields, with_named_schema

__all__ = ["ExportReport", "export_json", "to_json_value"]


@dataclass
class ExportReport:
    """What an export wrote."""

    source: str
    output: str
    messages: int = 0
    channels: int = 0
    skipped: dict[str, int] = field(default_factory=dict)  # topic -> payloads not msgpack
    source_complete: bool = True
    source_error: str = ""

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form."""
        return asdict(self)


def to_json_value(v: Any) -> Any:
    """msgpack-decoded value -> JSON-encodable value (bytes -> base64, non-finite -> None)."""
    if isinstance(v, dict):
        return {str(k): to_json_value(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [to_json_value(x) for x in v]
    if isinstance(v, bytes | bytearray | memoryview):
        return base64.b64encode(bytes(v)).decode("ascii")
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def export_json(path: str | Path, out: str | Path) -> ExportReport:
    """Write ``path`` (msgpack MCAP, complete or footer-less) as a json MCAP at ``out``."""
    src, dst = Path(path), Path(out)
    if dst.resolve() == src.resolve():
        raise ValueError("output must differ from input")
    rep = ExportReport(source=str(src), output=str(dst))
    profile = SessionInfo.from_metadata(read_metadata(src)).profile()
    reader = LogReader(src)
    schema_map: dict[int, int] = {}
    channel_map: dict[int, int] = {}
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    with atomic_write(dst) as f:
        w = Writer(f, compression=CompressionType.ZSTD)
        w.start(profile="", library="roger log export")
        for rec in reader.records():
            if isinstance(rec, Schema):
                schemas[rec.id] = rec
            elif isinstance(rec, Channel):
                channels[rec.id] = rec
            elif isinstance(rec, Metadata):
                w.add_metadata(rec.name, dict(rec.metadata))
            elif isinstance(rec, Message):
                ch = channels.get(rec.channel_id)
                if ch is None:
                    continue
                try:
                    value = msgpack.unpackb(rec.data, raw=False, strict_map_key=False)
                except Exception:
                    rep.skipped[ch.topic] = rep.skipped.get(ch.topic, 0) + 1
                    continue
                kind = kind_of(ch.topic)
                named = named_fields(kind, value, profile)
                if named is not None:
                    value["named"] = named
                cid = channel_map.get(ch.id)
                if cid is None:
                    sid = 0
                    s = schemas.get(ch.schema_id) if ch.schema_id else None
                    if s is not None and s.encoding == "jsonschema":
                        if s.id not in schema_map:
                            schema_map[s.id] = w.register_schema(
                                name=s.name, encoding="jsonschema",
                                data=with_named_schema(s.data, kind, profile))
                        sid = schema_map[s.id]
                    cid = w.register_channel(
                        topic=ch.topic,
                        message_encoding=MessageEncoding.JSON,
                        schema_id=sid,
                        metadata=dict(ch.metadata),
                    )
                    channel_map[ch.id] = cid
                data = json.dumps(
                    to_json_value(value), separators=(",", ":"), allow_nan=False
                ).encode()
                w.add_message(
                    cid,
                    log_time=rec.log_time,
                    data=data,
                    publish_time=rec.publish_time,
                    sequence=rec.sequence,
                )
                rep.messages += 1
        if not rep.messages and not reader.complete:  # nothing written: the atomic write aborts
            raise ValueError(f"{src} has no readable message to export (the file is cut "
                             f"short: {reader.error or 'no footer'})")
        w.finish()
    rep.channels = len(channel_map)
    rep.source_complete = reader.complete
    rep.source_error = reader.error
    return rep
