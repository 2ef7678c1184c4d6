"""Salvage a footer-less MCAP (killed writer) into a valid, indexed file.

Everything that :class:`~roger_daemon.recording.mcapio.LogReader` can read (every complete chunk
up to the first damaged record, plus metadata and attachments) is rewritten, in file order, by a
fresh ``Writer`` that adds the summary, indexes and footer. Channel and schema ids are remapped;
log time, publish time, sequence and payload bytes are kept exactly.
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path

from mcap.records import Attachment, Channel, Header, Message, Metadata, Schema
from mcap.writer import CompressionType, Writer

from roger_daemon.atomic import atomic_write, fsync_dir
from roger_daemon.recording.mcapio import LogReader

__all__ = [
    "RecoverReport",
    "default_output",
    "recover",
    "recover_directory",
    "recover_in_place",
]


@dataclass(frozen=True)
class RecoverReport:
    """What a recovery kept."""

    source: str
    output: str
    complete: bool  # the source already had its footer
    messages: int  # messages written to the output
    chunks: int  # complete chunks read from the source
    channels: int
    metadata: int
    attachments: int
    bytes_total: int  # source size
    bytes_valid: int  # readable prefix of the source
    error: str  # why reading stopped early ('' if it did not)

    @property
    def bytes_dropped(self) -> int:
        """Unreadable tail of the source, in bytes."""
        return self.bytes_total - self.bytes_valid

    def to_dict(self) -> dict[str, object]:
        """JSON-ready form."""
        return {**asdict(self), "bytes_dropped": self.bytes_dropped}


def default_output(path: str | Path) -> Path:
    """``X.mcap`` -> ``X.recovered.mcap`` next to it."""
    p = Path(path)
    return p.with_name(p.stem + ".recovered.mcap")


def recover(
    path: str | Path,
    out: str | Path | None = None,
    *,
    chunk_size: int = 1024 * 1024,
    compression: CompressionType = CompressionType.ZSTD,
) -> RecoverReport:
    """Read ``path`` as far as it is readable and write a finished MCAP to ``out``.

    ``out`` defaults to :func:`default_output`; it must differ from ``path`` (use
    :func:`recover_in_place` to replace a file). Raises ``ValueError`` if ``path`` is not an
    MCAP file at all (bad magic or no header); the output is then not written.
    """
    src = Path(path)
    dst = default_output(src) if out is None else Path(out)
    if dst.resolve() == src.resolve():
        raise ValueError("output must differ from input; use recover_in_place()")
    reader = LogReader(src)
    records = reader.records()
    first = next(records, None)
    if not isinstance(first, Header):
        raise ValueError(f"{src}: not an MCAP file ({reader.error or 'no header'})")
    schema_map: dict[int, int] = {}
    channel_map: dict[int, int] = {}
    pending_schemas: dict[int, Schema] = {}
    n_msg = n_meta = n_att = 0
    with atomic_write(dst) as f:
        w = Writer(f, chunk_size=chunk_size, compression=compression)
        w.start(profile=first.profile, library=first.library)
        for rec in records:
            if isinstance(rec, Schema):
                pending_schemas[rec.id] = rec
            elif isinstance(rec, Channel):
                if rec.id in channel_map:
                    continue
                sid = 0
                if rec.schema_id:
                    if rec.schema_id not in schema_map:
                        s = pending_schemas.get(rec.schema_id)
                        if s is None:
                            continue  # channel without its schema: its messages are dropped
                        schema_map[rec.schema_id] = w.register_schema(
                            name=s.name, encoding=s.encoding, data=s.data
                        )
                    sid = schema_map[rec.schema_id]
                channel_map[rec.id] = w.register_channel(
                    topic=rec.topic,
                    message_encoding=rec.message_encoding,
                    schema_id=sid,
                    metadata=dict(rec.metadata),
                )
            elif isinstance(rec, Message):
                cid = channel_map.get(rec.channel_id)
                if cid is None:
                    continue
                w.add_message(
                    cid,
                    log_time=rec.log_time,
                    data=rec.data,
                    publish_time=rec.publish_time,
                    sequence=rec.sequence,
                )
                n_msg += 1
            elif isinstance(rec, Metadata):
                w.add_metadata(rec.name, dict(rec.metadata))
                n_meta += 1
            elif isinstance(rec, Attachment):
                w.add_attachment(
                    create_time=rec.create_time,
                    log_time=rec.log_time,
                    name=rec.name,
                    media_type=rec.media_type,
                    data=rec.data,
                )
                n_att += 1
        w.finish()
    return RecoverReport(
        source=str(src),
        output=str(dst),
        complete=reader.complete,
        messages=n_msg,
        chunks=reader.chunks,
        channels=len(channel_map),
        metadata=n_meta,
        attachments=n_att,
        bytes_total=reader.bytes_total,
        bytes_valid=reader.bytes_valid,
        error=reader.error,
    )


def _unused(path: Path) -> Path:
    """``path``, or ``path.1``, ``path.2``, ... whichever does not exist yet."""
    out, k = path, 0
    while out.exists():
        k += 1
        out = path.with_name(f"{path.name}.{k}")
    return out


def recover_in_place(path: str | Path, *, keep_original: bool = False) -> RecoverReport:
    """Replace ``path`` by its recovered form atomically (same name, so session discovery and
    catch-up keep working). With ``keep_original`` the damaged file stays as ``X.mcap.damaged``.
    """
    src = Path(path)
    fd, tmpname = tempfile.mkstemp(prefix=f".{src.name}.", suffix=".recovering", dir=src.parent)
    os.close(fd)
    tmp = Path(tmpname)
    try:
        rep = recover(src, tmp)  # written durably (atomic_write) under a temporary name
        if keep_original:  # a second name for the damaged bytes; src itself is swapped atomically
            os.link(src, _unused(src.with_name(src.name + ".damaged")))
        os.replace(tmp, src)
        fsync_dir(src.parent)
    finally:
        if tmp.exists():
            tmp.unlink()
    return RecoverReport(**{**asdict(rep), "output": str(src)})


def recover_directory(directory: str | Path, robot: str | None = None,
                      *, keep_original: bool = True) -> list[RecoverReport]:
    """Recover in place every session file in ``directory`` that lacks its footer.

    For the daemon's start-up: after this every log is indexed and readable by any MCAP tool.
    Complete files are left alone (checked by reading their footer and summary only).
    Damaged originals are kept as ``X.mcap.damaged`` unless ``keep_original`` is false.

    Never raises for one bad file: a file that is not MCAP at all is moved aside to
    ``X.mcap.damaged`` (``output`` is then ``""``); a file that cannot be rewritten (an OS
    error) is left as it is. Both are reported with their ``error``.
    """
    from roger_daemon.recording.files import list_session_files
    from roger_daemon.recording.mcapio import is_complete

    reports = []
    for sf in list_session_files(directory, robot=robot):
        if is_complete(sf.path):
            continue
        try:
            size = sf.path.stat().st_size
        except OSError:
            size = 0
        try:
            reports.append(recover_in_place(sf.path, keep_original=keep_original))
            continue
        except ValueError as exc:  # not even a header: move it out of the way
            error = str(exc)
            try:
                os.replace(sf.path, _unused(sf.path.with_name(sf.path.name + ".damaged")))
                error += "; moved aside to .damaged"
            except OSError as exc2:
                error += f"; could not move it aside ({exc2})"
        except Exception as exc:  # OSError (disk full, permissions), an mcap writer error
            error = f"could not recover it ({type(exc).__name__}: {exc}); left as it is"
        reports.append(RecoverReport(
            source=str(sf.path), output="", complete=False, messages=0, chunks=0,
            channels=0, metadata=0, attachments=0, bytes_total=size, bytes_valid=0,
            error=error))
    return reports
