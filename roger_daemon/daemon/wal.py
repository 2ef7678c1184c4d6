"""Write-ahead log of the daemon's learning decisions: acknowledged means durable.

Every pair the daemon learns is appended here (one record: its index in the model, tick,
perception ``x``, action ``y`` and label), and so is every replacement of the model by a fresh
one (``reset`` control, a start without checkpoint, ``--fresh``). The service loop commits the
log (``fdatasync``) before it publishes anything that reports ``updates`` (a prediction or a
status) and at least every ``durability.commit_ms``; so every pair a sender has seen counted in
``updates`` is on disk, and survives kill -9 and power loss. Start-up recovery loads the newest
checkpoint and re-learns the records written after it (``wal_seq`` in the checkpoint's meta).

File layout: ``<checkpoint dir>/<robot>/wal/wal-<first seq>.log``, one segment per daemon
life and per checkpoint (a new segment starts when a checkpoint is written, so that old
segments can be deleted whole). A segment is a sequence of frames::

    u32 length | u32 crc32(payload) | payload (msgpack map)

followed by zeros (segments are zero-filled ahead of the records; see ``PREALLOCATE``).

Payload maps carry ``k`` (``"pair"`` or ``"fresh"``) and ``s`` (the record's sequence number,
increasing by one over the robot's whole history); pair records add ``i`` (the model's
``n_learned`` before learning it), ``tick``, ``x``/``y`` (float64 little-endian bytes) and
``label``. A frame that is short or fails its CRC ends the segment (a torn write of a killed
daemon: never acknowledged, since its commit had not returned). Segments are never appended
to after the life that wrote them; each start opens a new one.

The record is the daemon's decision, not its input, so it is also what a session log needs to
replay the daemon without re-deriving its pairing (see ``docs/durability.md``).
"""

from __future__ import annotations

import logging
import os
import re
import struct
import threading
import time
import zlib
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import Executor, Future
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgpack
import numpy as np

from protocols.packing import packb
from roger_daemon.atomic import fsync_dir

__all__ = ["WalRecord", "WriteAheadLog", "read_records", "segments", "wal_dir"]

log = logging.getLogger(__name__)

_FRAME = struct.Struct("<II")
#: Segments are zero-filled ahead of the records, this much at a time: overwriting blocks
#: that exist lets ``fdatasync`` flush data only, without a journal commit for a new file
#: size (measured on ext4 under load: the sync's p99 13-18 ms instead of 17-95 ms).
PREALLOCATE = 1 << 20
_NAME = re.compile(r"^wal-(\d{12})\.log$")
_MAX_RECORD = 1 << 20


@dataclass(frozen=True)
class WalRecord:
    """One decision read back: a learned pair (``kind == "pair"``) or a fresh model."""

    kind: str
    seq: int
    index: int = -1
    tick: int = -1
    x: np.ndarray | None = None
    y: np.ndarray | None = None
    label: str = ""


def wal_dir(checkpoint_dir: Path, robot: str) -> Path:
    """Where one robot's write-ahead log lives (next to its checkpoints)."""
    return Path(checkpoint_dir) / robot / "wal"


def segments(directory: Path) -> list[tuple[int, Path]]:
    """``(first seq, path)`` of every segment, oldest first."""
    if not directory.is_dir():
        return []
    out = []
    for p in directory.iterdir():
        m = _NAME.match(p.name)
        if m and p.is_file():
            out.append((int(m.group(1)), p))
    return sorted(out)


def _decode(payload: bytes) -> WalRecord | None:
    try:
        m: Any = msgpack.unpackb(payload, raw=False)
    except Exception:
        return None
    if not isinstance(m, dict) or not isinstance(m.get("s"), int):
        return None
    if m.get("k") == "fresh":
        return WalRecord("fresh", m["s"])
    if m.get("k") != "pair":
        return None
    try:
        x = np.frombuffer(m["x"], dtype="<f8").copy()
        y = np.frombuffer(m["y"], dtype="<f8").copy()
        return WalRecord("pair", m["s"], int(m["i"]), int(m["tick"]), x, y, str(m["label"]))
    except (KeyError, TypeError, ValueError):
        return None


def _read_segment(path: Path) -> Iterator[WalRecord]:
    data = path.read_bytes()
    pos = 0
    while pos + _FRAME.size <= len(data):
        length, crc = _FRAME.unpack_from(data, pos)
        end = pos + _FRAME.size + length
        if length == 0 or length > _MAX_RECORD or end > len(data):  # zeros: the end
            return
        payload = data[pos + _FRAME.size: end]
        if zlib.crc32(payload) != crc:
            return
        rec = _decode(payload)
        if rec is None:
            return
        yield rec
        pos = end


def read_records(directory: Path, after_seq: int = -1) -> list[WalRecord]:
    """Every readable record with ``seq > after_seq``, in order (torn tails skipped)."""
    out: list[WalRecord] = []
    for _, path in segments(directory):
        out.extend(r for r in _read_segment(path) if r.seq > after_seq)
    return out


class WriteAheadLog:
    """The appending side: one open segment, group commit by :meth:`commit`.

    Parameters
    ----------
    directory
        The robot's ``wal`` directory (created if missing).
    next_seq
        Sequence number of the next record (one past the last readable one on disk).
    sync
        ``False`` skips ``fdatasync`` (records still reach the OS: they survive kill -9 but
        not power loss). For benchmarks of the cost only.
    """

    def __init__(self, directory: Path, next_seq: int, *, sync: bool = True) -> None:
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.sync = sync
        self.next_seq = next_seq
        self.durable_seq = next_seq - 1  # every record <= this is on disk
        self.commits = 0
        self.commit_ms_max = 0.0
        self.commit_ms: deque[float] = deque(maxlen=1000)  # the latest commits' durations
        self._fd = -1
        self._pos = self._end = 0
        self._dirty_since: int | None = None
        #: the monotonic clock of the appends' age (:meth:`due`); the daemon sets its own
        #: (``Service.clock``), whose ``now`` it passes to :meth:`commit_early`
        self.clock: Callable[[], int] = time.monotonic_ns
        self._lock = threading.Lock()  # the bookkeeping shared with a background commit
        self._inflight: Future[None] | None = None
        self._open(next_seq)

    @property
    def last_seq(self) -> int:
        """Sequence number of the newest record appended (-1 if none ever)."""
        return self.next_seq - 1

    def _open(self, seq: int) -> None:
        path = self.directory / f"wal-{seq:012d}.log"
        # A segment of this name exists only if the previous life wrote no readable record
        # into it (else next_seq would be past it): whatever it holds is a torn write.
        self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        self._pos = 0
        self._end = 0
        self._extend(PREALLOCATE)
        fsync_dir(self.directory)

    def _extend(self, at_least: int) -> None:
        """Zero-fill the segment past ``_end`` (a frame of zeros reads as the end)."""
        grow = max(PREALLOCATE, at_least)
        os.pwrite(self._fd, bytes(grow), self._end)
        os.fsync(self._fd)  # the new size is durable once, not at every commit
        self._end += grow

    def _append(self, rec: dict[str, Any]) -> int:
        seq = self.next_seq
        payload = packb({**rec, "s": seq})
        frame = _FRAME.pack(len(payload), zlib.crc32(payload)) + payload
        if self._pos + len(frame) + _FRAME.size > self._end:
            self._extend(len(frame) + _FRAME.size)
        os.pwrite(self._fd, frame, self._pos)
        self._pos += len(frame)
        with self._lock:
            self.next_seq += 1
            if self._dirty_since is None:
                self._dirty_since = self.clock()
        return seq

    def append_pair(self, index: int, tick: int, x: np.ndarray, y: np.ndarray,
                    label: str) -> int:
        """Record that the pair ``(x, y)`` of ``tick`` became the model's pair ``index``."""
        return self._append({
            "k": "pair", "i": int(index), "tick": int(tick), "label": label,
            "x": np.ascontiguousarray(x, dtype="<f8").tobytes(),
            "y": np.ascontiguousarray(y, dtype="<f8").tobytes(),
        })

    def append_fresh(self) -> int:
        """Record that the model was replaced by a fresh one."""
        return self._append({"k": "fresh"})

    @property
    def dirty(self) -> bool:
        """True if records were appended since the last commit."""
        return self._dirty_since is not None

    def due(self, now_ns: int, max_delay_ns: int) -> bool:
        """True if the oldest uncommitted record is at least ``max_delay_ns`` old."""
        return self._dirty_since is not None and now_ns - self._dirty_since >= max_delay_ns

    def commit(self) -> None:
        """Make every appended record durable (one ``fdatasync`` for the whole group).

        Raises the error of a failed background commit (:meth:`commit_early`)."""
        self._reap(wait=False)
        if self._dirty_since is None:
            return
        self._sync(self.next_seq - 1)

    def commit_durations(self) -> list[float]:
        """The latest commits' durations (ms), a copy: background commits append to them."""
        with self._lock:
            return list(self.commit_ms)

    def commit_early(self, now_ns: int, max_delay_ns: int, executor: Executor | None) -> None:
        """The loop's commit between acknowledgements: synchronous once the oldest uncommitted
        record is ``max_delay_ns`` old; before that, with ``executor``, a commit of the
        records appended so far started in the background (unless one is running), which
        commits again as long as records were appended while it ran (:meth:`_sync_chasing`),
        so that the commit before the next acknowledgement usually finds nothing left to do
        (docs/durability.md). Raises the error of a failed background commit."""
        self._reap(wait=False)
        if self._dirty_since is None:
            return
        if self.due(now_ns, max_delay_ns):
            self._sync(self.next_seq - 1)
        elif executor is not None and self._inflight is None:
            self._inflight = executor.submit(self._sync_chasing, self.next_seq - 1)

    def _sync_chasing(self, target: int) -> None:
        """A background commit: :meth:`_sync` up to ``target``, then again up to the newest
        record while some were appended meanwhile. The loop, idle between a lockstep tick's
        last learned pair and the next perception, then finds its log durable when it
        answers, instead of committing with the answer waiting (docs/durability.md)."""
        while True:
            self._sync(target)
            with self._lock:
                newest = self.next_seq - 1
            if newest <= target:
                return
            target = newest

    def _sync(self, target: int) -> None:
        """``fdatasync``: the records up to ``target`` (appended before the call) are durable;
        the log stays dirty if more were appended meanwhile (a background commit)."""
        t0 = time.perf_counter_ns()
        if self.sync:
            os.fdatasync(self._fd)
        ms = (time.perf_counter_ns() - t0) / 1e6
        with self._lock:
            self.commit_ms.append(ms)
            self.commit_ms_max = max(self.commit_ms_max, ms)
            self.commits += 1
            self.durable_seq = max(self.durable_seq, target)
            if self.next_seq - 1 == target:
                self._dirty_since = None

    def _reap(self, *, wait: bool) -> None:
        """Forget a finished background commit (raising its error); ``wait``: also one that
        is still running (before the file is closed or replaced)."""
        job = self._inflight
        if job is None or not (wait or job.done()):
            return
        self._inflight = None
        job.result()

    def rotate(self) -> None:
        """Commit, then continue in a new segment (called after a checkpoint is taken)."""
        self._reap(wait=True)
        self.commit()
        os.close(self._fd)
        self._open(self.next_seq)

    def prune(self, covered_seq: int) -> int:
        """Delete whole segments whose records all have ``seq <= covered_seq`` (a durable
        checkpoint holds them); never the open one. Returns the number deleted."""
        segs = segments(self.directory)
        gone = 0
        for (_first, path), (nxt, _) in zip(segs, segs[1:], strict=False):
            if nxt - 1 <= covered_seq:
                path.unlink()
                gone += 1
        return gone

    def close(self) -> None:
        """Commit and close (idempotent)."""
        if self._fd < 0:
            return
        self._reap(wait=True)
        self.commit()
        os.close(self._fd)
        self._fd = -1


@dataclass
class Replayed:
    """What :func:`replay_into` did."""

    pairs: int = 0
    fresh: int = 0
    first_tick: int | None = None
    last_tick: int | None = None
    stopped: str = ""  # why replay stopped before the end ("" if it did not)
    next_seq: int = 0  # sequence number for the next record


def replay_into(rt: Any, directory: Path, after_seq: int) -> Replayed:
    """Re-learn into ``rt`` (a RobotRuntime, WAL not attached) every decision after
    ``after_seq``: ``fresh`` records reset the model, pair records are learned in order.

    A pair whose index is not the model's ``n_learned`` (a gap: e.g. the segments after a
    lost checkpoint were pruned) stops the replay; the rest is reported, not guessed.
    """
    out = Replayed()
    records = read_records(directory)
    out.next_seq = records[-1].seq + 1 if records else 0
    for r in records:
        if r.seq <= after_seq:
            continue
        if r.kind == "fresh":
            rt.reset()
            out.fresh += 1
            continue
        if r.index != rt.updates:
            out.stopped = (f"record {r.seq} is pair {r.index} but the model has {rt.updates} "
                           "pairs (a gap in the log); the rest is not used")
            break
        assert r.x is not None and r.y is not None
        rt.relearn(r.x, r.y, r.label, r.tick)
        out.pairs += 1
        out.first_tick = r.tick if out.first_tick is None else out.first_tick
        out.last_tick = r.tick
    return out


def start(rt: Any, directory: Path, *, checkpoint_seq: int | None, replay: bool,
          fresh: bool) -> Replayed:
    """Start-up of one robot's log: replay what follows the checkpoint (``replay``), then
    attach a new segment to ``rt`` (``rt.wal``).

    ``checkpoint_seq`` is the checkpoint's ``wal_seq`` (None: no checkpoint, or one written
    without the log; then every record is replayed, from the first ``fresh`` one). A model
    the log cannot rebuild (``fresh``: ``--fresh``, or no checkpoint and no log) starts a new
    history with a ``fresh`` record. After a replay the caller writes a checkpoint (its
    ``wal_seq`` covers every record on disk, including any after a gap).
    """
    rep = (replay_into(rt, directory, -1 if checkpoint_seq is None else checkpoint_seq)
           if replay else Replayed(next_seq=_next_seq(directory)))
    rt.session_resets = 0
    rt.wal = WriteAheadLog(directory, rep.next_seq)
    if fresh:
        rt.wal.append_fresh()
        rt.wal.commit()
    return rep


def _next_seq(directory: Path) -> int:
    records = read_records(directory)
    return records[-1].seq + 1 if records else 0
