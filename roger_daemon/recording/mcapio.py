"""Linear, crash-tolerant MCAP reading (complete files and footer-less files alike).

:class:`LogReader` walks a file front to back with mcap's ``StreamReader`` (chunks emitted
whole, then unpacked with CRC checks) and stops quietly at the first record it cannot read: a
truncated tail, a corrupt chunk, a bad length. Everything before that point is yielded in file
order, which is the writer's call order. Whether the footer was reached, where the readable
data ends and why reading stopped are recorded on the reader.

This is the one reader behind ``log info``, ``log recover``, ``log export``, replay and log-tail
catch-up, so they all agree on what a damaged file contains.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from mcap.records import (
    Attachment,
    Channel,
    Chunk,
    DataEnd,
    Footer,
    Header,
    McapRecord,
    Message,
    Metadata,
    Schema,
)
from mcap.stream_reader import StreamReader, breakup_chunk

__all__ = [
    "MCAP_MAGIC",
    "LogMessage",
    "LogReader",
    "is_complete",
    "not_an_mcap_file",
    "read_metadata",
    "topics_of",
]

#: The first 8 bytes of every MCAP file (and the last 8 of a finished one).
MCAP_MAGIC = b"\x89MCAP0\r\n"


def not_an_mcap_file(path: str | Path) -> str:
    """Why ``path`` cannot be read as an MCAP log ("" if it starts like one).

    The one input check of every command that reads a log (``log info|recover|export``,
    ``replay``): a missing path, a directory, an empty file or one without the MCAP magic.
    """
    p = Path(path)
    if not p.exists():
        return f"{p}: no such file"
    if p.is_dir():
        return f"{p} is a directory; expected an MCAP file (roger-<robot>-<start>.mcap)"
    try:
        with open(p, "rb") as f:
            head = f.read(len(MCAP_MAGIC))
    except OSError as exc:
        return f"{p}: cannot read ({exc.strerror or exc})"
    if head != MCAP_MAGIC:
        what = "an empty file" if not head else f"starts with {head[:8]!r}"
        return f"{p} is not an MCAP file ({what}; an MCAP file starts with {MCAP_MAGIC!r})"
    return ""


@dataclass(frozen=True)
class LogMessage:
    """One message with its channel and schema resolved."""

    channel: Channel
    schema: Schema | None
    message: Message

    @property
    def topic(self) -> str:
        """The channel's topic (the Zenoh key expression)."""
        return self.channel.topic


@dataclass
class LogReader:
    """Read one MCAP file linearly, tolerating truncation and corruption.

    Iterate :meth:`records` or :meth:`messages` once; afterwards ``complete``, ``error``,
    ``bytes_valid``, ``chunks``, ``messages_read`` and ``metadata`` describe what was found.
    """

    path: Path
    validate_crcs: bool = True
    header: Header | None = None
    complete: bool = False
    error: str = ""
    bytes_total: int = 0
    bytes_valid: int = 0
    chunks: int = 0
    messages_read: int = 0
    metadata: list[Metadata] = field(default_factory=list)
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    unknown_channel: int = 0

    def __post_init__(self) -> None:
        self.path = Path(self.path)

    def records(self) -> Iterator[McapRecord]:
        """Data-section records in file order: Header, Schema, Channel, Message, Metadata,
        Attachment (chunks unpacked; indexes and the summary skipped)."""
        with open(self.path, "rb") as f:
            self.bytes_total = os.fstat(f.fileno()).st_size
            limit = max(self.bytes_total, 1)
            it = StreamReader(f, emit_chunks=True, record_size_limit=limit).records
            in_summary = False
            while True:
                try:
                    rec = next(it)
                except StopIteration:
                    break
                except Exception as exc:  # any unreadable record ends the readable prefix
                    if type(exc).__name__ == "EndOfFile" and self.bytes_valid == self.bytes_total:
                        self.error = "no footer (file ends after a complete record)"
                    else:
                        self.error = f"unreadable record at byte {self.bytes_valid}: " + (
                            self._describe(exc)
                        )
                    break
                if isinstance(rec, Chunk):
                    try:
                        inner = breakup_chunk(rec, validate_crc=self.validate_crcs)
                    except Exception as exc:
                        self.error = "corrupt chunk: " + self._describe(exc)
                        break
                    self.chunks += 1
                    self.bytes_valid = f.tell()
                    for r in inner:
                        yield from self._note(r)
                    continue
                if isinstance(rec, Footer):
                    in_summary = True
                    # StreamReader reads the closing magic right after the footer and stops.
                    try:
                        next(it)
                    except StopIteration:
                        self.complete = True
                    except Exception as exc:
                        self.error = "bad closing magic: " + self._describe(exc)
                    self.bytes_valid = f.tell()
                    break
                self.bytes_valid = f.tell()
                if isinstance(rec, DataEnd):
                    in_summary = True
                    continue
                if in_summary:
                    continue  # summary repeats schemas/channels; indexes are rebuilt on write
                if isinstance(rec, Header):
                    self.header = rec
                yield from self._note(rec)

    def _note(self, rec: McapRecord) -> Iterator[McapRecord]:
        if isinstance(rec, Schema):
            self.schemas[rec.id] = rec
        elif isinstance(rec, Channel):
            self.channels[rec.id] = rec
        elif isinstance(rec, Metadata):
            self.metadata.append(rec)
        elif isinstance(rec, Message):
            self.messages_read += 1
        elif not isinstance(rec, Attachment | Header):
            return
        yield rec

    def messages(self) -> Iterator[LogMessage]:
        """Messages in file order, with channel and schema resolved."""
        for rec in self.records():
            if isinstance(rec, Message):
                ch = self.channels.get(rec.channel_id)
                if ch is None:
                    self.unknown_channel += 1
                    continue
                schema = self.schemas.get(ch.schema_id) if ch.schema_id else None
                yield LogMessage(ch, schema, rec)

    @staticmethod
    def _describe(exc: BaseException) -> str:
        name = type(exc).__name__
        text = str(exc)
        if name == "EndOfFile":
            return "truncated (end of file inside a record)"
        return f"{name}: {text}" if text else name


def read_metadata(path: str | Path) -> dict[str, str]:
    """The ``roger.session`` metadata of a file (read from the front; works without a footer)."""
    from roger_daemon.recording.metadata import METADATA_NAME

    reader = LogReader(Path(path))
    for rec in reader.records():
        if isinstance(rec, Metadata) and rec.name == METADATA_NAME:
            return dict(rec.metadata)
        if isinstance(rec, Message | Chunk):
            break
    return {}


def topics_of(path: str | Path) -> list[str]:
    """Channel topics of a file: from the summary when there is one, else by a linear read."""
    from mcap.reader import SeekingReader

    try:
        with open(path, "rb") as f:
            summary = SeekingReader(f).get_summary()
        if summary is not None:
            return sorted({c.topic for c in summary.channels.values()})
    except Exception:
        pass
    reader = LogReader(Path(path))
    for _ in reader.records():
        pass
    return sorted({c.topic for c in reader.channels.values()})


def is_complete(path: str | Path) -> bool:
    """True if the file ends with a readable footer and magic (a cleanly finished file)."""
    from mcap.reader import SeekingReader

    try:
        with open(path, "rb") as f:
            SeekingReader(f).get_summary()
            f.seek(-8, os.SEEK_END)
            return f.read(8) == b"\x89MCAP0\r\n"
    except Exception:
        return False
