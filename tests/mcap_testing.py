"""MCAP inspection helpers shared by the log-tool and regression-session tests."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path

from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Message, Metadata, Schema
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.writer import Writer

from roger_daemon.recording.mcapio import LogReader

__all__ = ["chunk_ends", "copy_log", "messages"]


def copy_log(src: Path, dst: Path, *, keep: Callable[[str], bool] = lambda topic: True,
             edit: Callable[[str, int, bytes], bytes] | None = None,
             metadata: Callable[[str, Mapping[str, str]], dict[str, str]] | None = None
             ) -> Path:
    """Copy the log ``src`` to ``dst`` record by record: only the channels whose topic
    ``keep`` accepts, each payload through ``edit(topic, index_in_topic, data)`` and each
    metadata record through ``metadata(name, fields)``; times and sequence numbers kept."""
    reader = LogReader(src)
    seen: dict[str, int] = {}
    schemas: dict[int, int] = {}
    channels: dict[int, int] = {}
    topics: dict[int, str] = {}
    with open(dst, "wb") as f:
        w = Writer(f)
        w.start()
        for rec in reader.records():
            if isinstance(rec, Schema):
                schemas[rec.id] = w.register_schema(rec.name, rec.encoding, rec.data)
            elif isinstance(rec, Channel) and keep(rec.topic):
                channels[rec.id] = w.register_channel(rec.topic, rec.message_encoding,
                                                      schemas.get(rec.schema_id, 0),
                                                      dict(rec.metadata))
                topics[rec.id] = rec.topic
            elif isinstance(rec, Metadata):
                fields = dict(rec.metadata)
                w.add_metadata(rec.name, metadata(rec.name, fields) if metadata else fields)
            elif isinstance(rec, Message) and rec.channel_id in channels:
                t = topics[rec.channel_id]
                i = seen.get(t, 0)
                seen[t] = i + 1
                data = edit(t, i, rec.data) if edit else rec.data
                w.add_message(channels[rec.channel_id], rec.log_time, data, rec.publish_time,
                              rec.sequence)
        w.finish()
    return dst


def chunk_ends(path: Path) -> list[tuple[int, int]]:
    """(end offset, messages) of every chunk, from mcap's own chunk index."""
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
        assert summary is not None
        out = []
        for ci in summary.chunk_indexes:
            f.seek(ci.chunk_start_offset)
            rec = next(StreamReader(f, skip_magic=True, emit_chunks=True).records)
            assert isinstance(rec, Chunk)
            n = sum(type(r).__name__ == "Message" for r in breakup_chunk(rec))
            out.append((ci.chunk_start_offset + ci.chunk_length, n))
    return out


def messages(path: Path) -> list[tuple[str, int, int, int, bytes]]:
    with open(path, "rb") as f:
        return [(c.topic, m.log_time, m.publish_time, m.sequence, m.data)
                for _, c, m in make_reader(f).iter_messages(log_time_order=False)]
