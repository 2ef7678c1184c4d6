"""SessionRecorder: one MCAP file per session and robot, crash-bounded, rotated.

Durability model (measured in ``roger_daemon.bench.recorder``):

* The mcap ``Writer`` keeps the open chunk in memory, so :meth:`SessionRecorder.poll` closes the
  chunk (``Writer.flush()``: finish chunk, write it and its message indexes, flush Python's
  buffer to the OS) once ``flush_interval_s`` has passed since the last flush. A SIGKILL then
  loses only what was written since the last flush: at most ``flush_interval_s`` plus one loop
  period. (An OS crash or power loss can lose more unless ``fsync=True``.)
* Chunks are also closed when they reach ``chunk_size`` bytes (uncompressed).
* :meth:`close` writes the summary (schemas, channels, statistics, chunk and metadata indexes)
  and the footer, so a cleanly closed file is indexed. A file without a footer (killed writer)
  is salvaged by :func:`roger_daemon.recording.recover.recover`.

The recorder is not thread-safe: call it from the one loop that owns it.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from mcap.well_known import MessageEncoding
from mcap.writer import CompressionType, Writer

from protocols import keys as keyexpr
from protocols.errors import ProtocolError
from roger_daemon.recording import files
from roger_daemon.recording.metadata import METADATA_NAME
from roger_daemon.recording.schemas import SCHEMA_ENCODING, schema_bytes, schema_name

__all__ = ["COMPRESSIONS", "RecorderStats", "SessionRecorder"]

log = logging.getLogger(__name__)

COMPRESSIONS = {
    "zstd": CompressionType.ZSTD,
    "lz4": CompressionType.LZ4,
    "none": CompressionType.NONE,
}


@dataclass
class RecorderStats:
    """Counters of one recorder (all parts)."""

    messages: int = 0
    parts: int = 0
    flushes: int = 0
    bytes_closed_parts: int = 0
    bytes_current: int = 0

    @property
    def bytes(self) -> int:
        """Bytes handed to the OS so far, all parts."""
        return self.bytes_closed_parts + self.bytes_current


def _library() -> str:
    from roger_daemon import __version__

    try:
        from importlib.metadata import version

        mcap_v = version("mcap")
    except Exception:  # pragma: no cover - metadata missing in odd installs
        mcap_v = "?"
    return f"roger/{__version__} mcap-python/{mcap_v}"


class SessionRecorder:
    """Record one session of one robot into MCAP files in ``directory``.

    Parameters
    ----------
    directory
        Where the files go (created if missing).
    robot
        The robot id; part of the file name.
    metadata
        The ``roger.session`` map, usually from :func:`~roger_daemon.recording.session_metadata`.
        The recorder adds ``session_id``, ``part``, ``start_time_utc``, ``start_ns`` and its own
        settings.
    flush_interval_s
        Close the open chunk and flush to the OS at least this often (via :meth:`poll`).
    flush_phase
        The first flush comes this fraction of ``flush_interval_s`` after the first
        :meth:`poll` (``0 < flush_phase <= 1``; then every ``flush_interval_s``). A daemon
        recording several robots gives each recorder its own phase, so that their flushes
        (each compresses a chunk and writes it) do not all fall in one cycle of its loop.
    chunk_size
        Close a chunk when it reaches this many uncompressed bytes.
    rotate_bytes, rotate_s
        Start a new part when the current one reaches this size or age (None: never).
    compression
        ``"zstd"`` (default), ``"lz4"`` or ``"none"``.
    fsync
        Also ``os.fsync`` on every flush and rotation (power-loss safety; costs disk latency in the
        loop). The file is always fsynced on :meth:`close`.
    start_ns
        Session start (Unix ns) for the file name; default now.
    """

    def __init__(
        self,
        directory: str | Path,
        *,
        robot: str,
        metadata: Mapping[str, str],
        flush_interval_s: float = 1.0,
        flush_phase: float = 1.0,
        chunk_size: int = 256 * 1024,
        rotate_bytes: int | None = 256 * 1024 * 1024,
        rotate_s: float | None = 3600.0,
        compression: str = "zstd",
        fsync: bool = False,
        start_ns: int | None = None,
    ) -> None:
        keyexpr.validate_robot_id(robot)
        if compression not in COMPRESSIONS:
            raise ValueError(f"compression must be one of {sorted(COMPRESSIONS)}")
        if flush_interval_s <= 0:
            raise ValueError("flush_interval_s must be > 0")
        if not 0 < flush_phase <= 1:
            raise ValueError(f"flush_phase must be in (0, 1], got {flush_phase!r}")
        bad = [k for k, v in metadata.items() if not isinstance(k, str) or not isinstance(v, str)]
        if bad:
            raise TypeError(f"metadata must map str to str; bad keys: {bad}")
        self._dir = Path(directory)
        self._dir.mkdir(parents=True, exist_ok=True)
        self._robot = robot
        self._meta = dict(metadata)
        self._flush_ns = int(flush_interval_s * 1e9)
        self._first_flush_ns = int(flush_phase * self._flush_ns)
        self._chunk_size = int(chunk_size)
        self._rotate_bytes = rotate_bytes
        self._rotate_ns = None if rotate_s is None else int(rotate_s * 1e9)
        self._compression = compression
        self._fsync = fsync
        self._start_ns = time.time_ns() if start_ns is None else int(start_ns)
        self._session_id = files.session_id_for(self._dir, robot, self._start_ns)
        self._library = _library()
        self._stats = RecorderStats()
        self._paths: list[Path] = []
        self._part = -1
        self._closed = False
        # per-part state
        self._file: IO[bytes] | None = None
        self._writer: Writer | None = None
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self._dirty = False
        # poll clock (the caller's; set on first poll)
        self._last_flush: int | None = None
        self._part_started: int | None = None
        self._open_part(0)

    # -- public ------------------------------------------------------------------------------

    @property
    def path(self) -> Path:
        """The file being written (the latest part)."""
        return self._paths[-1]

    @property
    def paths(self) -> list[Path]:
        """Every part written so far, in order."""
        return list(self._paths)

    @property
    def metadata(self) -> dict[str, str]:
        """The ``roger.session`` map it was given (a copy; each part adds its own keys)."""
        return dict(self._meta)

    @property
    def session_id(self) -> str:
        """``roger-<robot>-<start>``: the common stem of this session's parts."""
        return self._session_id

    @property
    def stats(self) -> RecorderStats:
        """Counters (a live object)."""
        return self._stats

    @property
    def closed(self) -> bool:
        """True after :meth:`close`."""
        return self._closed

    def write(
        self, key: str, payload: bytes, *, log_time_ns: int, publish_time_ns: int, sequence: int
    ) -> None:
        """Append one message of key expression ``key`` (payload stored verbatim).

        ``log_time_ns`` is when this process received (or sent) it, ``publish_time_ns`` the
        sender's time (the payload's ``stamp_ns``), ``sequence`` the tick. Cheap: no I/O except
        when a chunk reaches ``chunk_size``.
        """
        if self._closed:
            raise RuntimeError("SessionRecorder is closed")
        w = self._writer
        assert w is not None
        cid = self._channels.get(key)
        if cid is None:
            cid = self._register(key)
        w.add_message(
            cid,
            log_time=int(log_time_ns),
            data=bytes(payload),
            publish_time=int(publish_time_ns),
            sequence=int(sequence) & 0xFFFFFFFF,
        )
        self._dirty = True
        self._stats.messages += 1

    def poll(self, now_ns: int) -> bool:
        """Flush and rotate when due; call every loop cycle with one steady clock (ns).
        True when it flushed (the call's cost was a chunk's compression and write).

        The clock is the caller's (``time.monotonic_ns()`` is fine); only differences matter.
        Cheap when nothing is due (two comparisons).
        """
        if self._closed:
            return False
        if self._last_flush is None or self._part_started is None:
            self._part_started = now_ns
            self._last_flush = now_ns - self._flush_ns + self._first_flush_ns
            return False
        if now_ns - self._last_flush < self._flush_ns:
            return False
        self.flush()
        self._last_flush = now_ns
        if self._rotation_due(now_ns):
            self._rotate()
            self._part_started = now_ns
        return True

    def flush(self) -> None:
        """Close the open chunk and hand everything to the OS now (fsync if configured)."""
        if self._closed or self._writer is None or self._file is None:
            return
        if self._dirty:
            self._writer.flush()
            self._dirty = False
            self._stats.flushes += 1
            if self._fsync:
                os.fsync(self._file.fileno())
        self._stats.bytes_current = self._file.tell()

    def close(self) -> None:
        """Finish the file: summary, indexes, footer; fsync and close. Idempotent."""
        if self._closed:
            return
        self._closed = True
        self._finish_part(fsync=True)

    def __enter__(self) -> SessionRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- internals ---------------------------------------------------------------------------

    def _rotation_due(self, now_ns: int) -> bool:
        assert self._part_started is not None
        if self._rotate_ns is not None and now_ns - self._part_started >= self._rotate_ns:
            return True
        return self._rotate_bytes is not None and self._stats.bytes_current >= self._rotate_bytes

    def _rotate(self) -> None:
        self._finish_part(fsync=self._fsync)
        self._open_part(self._part + 1)

    def _open_part(self, part: int) -> None:
        path = files.part_path(self._dir, self._session_id, part)
        f = open(path, "xb")  # closed in _finish_part
        w = Writer(
            f,
            chunk_size=self._chunk_size,
            compression=COMPRESSIONS[self._compression],
        )
        w.start(profile="", library=self._library)
        meta = {
            **self._meta,
            "session_id": self._session_id,
            "part": str(part),
            "start_ns": str(self._start_ns),
            "start_time_utc": time.strftime(
                "%Y-%m-%dT%H:%M:%SZ", time.gmtime(self._start_ns // 1_000_000_000)
            ),
            "recorder": (
                f"flush_interval_s={self._flush_ns / 1e9:g} chunk_size={self._chunk_size} "
                f"compression={self._compression}"
            ),
        }
        meta.setdefault("robot", self._robot)
        w.add_metadata(METADATA_NAME, meta)
        f.flush()
        self._file, self._writer = f, w
        self._channels, self._schemas = {}, {}
        self._dirty = False
        self._part = part
        self._paths.append(path)
        self._stats.parts += 1
        self._stats.bytes_current = f.tell()

    def _finish_part(self, *, fsync: bool) -> None:
        w, f = self._writer, self._file
        if w is None or f is None:
            return
        try:
            w.finish()
            f.flush()
            if fsync:
                os.fsync(f.fileno())
            self._stats.bytes_closed_parts += f.tell()
            self._stats.bytes_current = 0
        finally:
            f.close()
            self._writer = self._file = None

    def _register(self, key: str) -> int:
        w = self._writer
        assert w is not None
        meta: dict[str, str] = {}
        schema_id = 0
        try:
            robot, kind = keyexpr.parse(key)
        except ProtocolError:
            decision = keyexpr.parse_decision(key)  # roger/<robot>/daemon/<event>
            robot, kind = (decision[0], f"daemon.{decision[1]}") if decision else ("", "")
        if kind:
            meta = {"robot": robot, "kind": kind}
            sid = self._schemas.get(kind)
            if sid is None:
                sid = w.register_schema(
                    name=schema_name(kind), encoding=SCHEMA_ENCODING, data=schema_bytes(kind)
                )
                self._schemas[kind] = sid
            schema_id = sid
        cid: int = w.register_channel(
            topic=key,
            message_encoding=MessageEncoding.MessagePack,
            schema_id=schema_id,
            metadata=meta,
        )
        self._channels[key] = cid
        return cid


def header_fields(payload: bytes) -> tuple[int, int] | None:
    """``(tick, stamp_ns)`` from a ROGER payload's header, or None if it has none.

    For recorders that see raw payloads (``roger record``); the daemon has decoded messages.
    """
    import msgpack

    try:
        m: Any = msgpack.unpackb(payload, raw=False, strict_map_key=False)
    except Exception:
        return None
    if not isinstance(m, dict):
        return None
    tick, stamp = m.get("tick"), m.get("stamp_ns")
    if isinstance(tick, bool) or not isinstance(tick, int) or tick < 0:
        return None
    if isinstance(stamp, bool) or not isinstance(stamp, int) or stamp < 0:
        return None
    return tick, stamp
