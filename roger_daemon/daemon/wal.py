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
``label``. Reading back (:mod:`roger_daemon.daemon.wal_read`) keeps every frame its CRC proves
intact: a damaged one is reported with its offset and the reader resynchronises on the next
intact frame; damage at the end is a torn write of a killed daemon (never acknowledged, since
its commit had not returned). Segments are never appended to after the life that wrote them;
each start opens a new one, and a segment is cut to its records when the next one starts.

With the disk full the log cannot grow: the robot learns on what is left of the zero-filled
reserve, stops learning (:attr:`WriteAheadLog.accepting`) while a quarter of it is left
(:data:`LOW_WATER` by default), so that nothing learned goes unlogged, and tries to grow again
every :data:`RETRY_NS` (docs/durability.md, *Disk full*). The record is the daemon's decision,
not its input: what a session log needs to replay the daemon without re-deriving its pairing.
"""

from __future__ import annotations

import errno
import logging
import os
import threading
import time
import zlib
from collections import deque
from collections.abc import Callable
from concurrent.futures import Executor, Future
from pathlib import Path
from typing import Any

import numpy as np

from protocols.packing import packb
from roger_daemon.atomic import fsync_dir
from roger_daemon.daemon.wal_read import FRAME as _FRAME
from roger_daemon.daemon.wal_read import (
    WalDamage,
    WalRecord,
    read_log,
    read_records,
    segments,
)
from roger_daemon.daemon.wal_replay import Copies, Replayed, replay_into

__all__ = ["DISK_FULL_ERRNOS", "Copies", "Replayed", "WalDamage", "WalRecord", "WriteAheadLog",
           "read_log", "read_records", "replay_into", "segments", "start", "wal_dir"]

log = logging.getLogger(__name__)

#: Segments are zero-filled ahead of the records, by default this much at a time: overwriting
#: blocks that exist lets ``fdatasync`` flush data only, without a journal commit for a new
#: file size (measured on ext4 under load: the sync's p99 13-18 ms instead of 17-95 ms).
PREALLOCATE = 1 << 20
#: the errors that mean "no space" (a full file system, a user's quota)
DISK_FULL_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT})
#: with the disk full, learning stops once less than a quarter of the reserve is left (this,
#: by default): what is left takes the pairs already learned or in flight to a learner worker
#: (~0.3 kB a record), so nothing learned goes unlogged (docs/durability.md, *Disk full*)
LOW_WATER = PREALLOCATE // 4
#: how often a full log tries to grow again (on the loop's clock)
RETRY_NS = 1_000_000_000


def wal_dir(checkpoint_dir: Path, robot: str) -> Path:
    """Where one robot's write-ahead log lives (next to its checkpoints)."""
    return Path(checkpoint_dir) / robot / "wal"


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
    preallocate
        Bytes zero-filled ahead of the records at a time (``checkpoint.wal_reserve_kb``)
    """

    def __init__(self, directory: Path, next_seq: int, *, sync: bool = True,
                 preallocate: int = PREALLOCATE) -> None:
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.sync = sync
        self.preallocate, self.low_water = preallocate, preallocate // 4
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
        #: "" or why the log cannot grow (the disk is full; docs/durability.md, *Disk full*)
        self.full = ""
        self._retry_ns = 0
        self._fd, self._end = self._open(next_seq)

    @property
    def last_seq(self) -> int:
        """Sequence number of the newest record appended (-1 if none ever)."""
        return self.next_seq - 1

    def _open(self, seq: int) -> tuple[int, int]:
        """A new segment for records from ``seq`` on, zero-filled: ``(fd, its size)``. On an
        error (a full disk) nothing is left of it."""
        path = self.directory / f"wal-{seq:012d}.log"
        # A segment of this name exists only if the previous life wrote no readable record
        # into it (else next_seq would be past it): whatever it holds is a torn write.
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        try:
            size = _zero_fill(fd, 0, self.preallocate)
            os.fsync(fd)
            fsync_dir(self.directory)
        except OSError as exc:
            os.close(fd)
            path.unlink(missing_ok=True)
            err = exc.error if isinstance(exc, _Partial) else exc
            raise OSError(err.errno, err.strerror, str(path)) from None
        self._pos = 0
        return fd, size

    def _extend(self, at_least: int) -> None:
        """Zero-fill the segment past ``_end`` (a frame of zeros reads as the end); what was
        written before an error still counts."""
        try:
            self._end = _zero_fill(self._fd, self._end, max(self.preallocate, at_least))
        except _Partial as part:
            self._end = part.end
            raise part.error from None
        os.fsync(self._fd)  # the new size is durable once, not at every commit

    @property
    def reserve(self) -> int:
        """Bytes of the zero-filled reserve not yet taken by records."""
        return self._end - self._pos

    @property
    def accepting(self) -> bool:
        """Whether the robot may learn: the log can take what it learns (it can grow, or its
        reserve has more than a quarter of a preallocation left)."""
        return not self.full or self.reserve >= self.low_water

    def _grow(self, need: int) -> None:
        """Keep half a preallocation ahead of the records; with the disk full, try again at
        most every :data:`RETRY_NS` (and in :meth:`poll_space`). Raises only if ``need``
        bytes do not fit in what is left."""
        if self.reserve - need >= self.preallocate // 2:
            return
        if not self.full or self.clock() >= self._retry_ns:
            try:
                self._extend(need)
            except OSError as exc:
                if exc.errno not in DISK_FULL_ERRNOS:
                    raise
                self._now_full(exc)
        if self.reserve < need:
            raise OSError(errno.ENOSPC, f"write-ahead log {self.directory}: the disk is full "
                          f"and its reserve is used up ({self.reserve} bytes left)")

    def _now_full(self, exc: OSError) -> None:
        self._retry_ns = self.clock() + RETRY_NS
        if not self.full:
            self.full = f"{self.directory}: {os.strerror(exc.errno or errno.ENOSPC)}"
            log.error("write-ahead log %s cannot grow (%s): %d kB of reserve left; learning "
                      "stops below %d kB, predictions go on; retried every %g s",
                      self.directory, exc.strerror or exc, self.reserve >> 10,
                      self.low_water >> 10, RETRY_NS / 1e9)

    def poll_space(self, now_ns: int) -> bool:
        """With the disk full, try to grow (at most every :data:`RETRY_NS`); True once the log
        can grow again (learning resumes)."""
        if not self.full or now_ns < self._retry_ns:
            return False
        try:
            self._extend(self.preallocate)
        except OSError as exc:
            if exc.errno not in DISK_FULL_ERRNOS:
                raise
            self._retry_ns = now_ns + RETRY_NS
            return False
        log.warning("write-ahead log %s: space again (%d kB of reserve); learning resumes",
                    self.directory, self.reserve >> 10)
        self.full = ""
        return True

    def _append(self, rec: dict[str, Any]) -> int:
        seq = self.next_seq
        payload = packb({**rec, "s": seq})
        frame = _FRAME.pack(len(payload), zlib.crc32(payload)) + payload
        self._grow(len(frame) + _FRAME.size)
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
        pos = self._pos
        try:
            fd, end = self._open(self.next_seq)
        except OSError as exc:
            if exc.errno not in DISK_FULL_ERRNOS:
                raise
            log.warning("write-ahead log %s: no space for a new segment (%s); continuing in "
                        "the current one", self.directory, exc.strerror or exc)
            return
        os.ftruncate(self._fd, pos)  # its zero-filled rest is not needed any more
        os.close(self._fd)
        self._fd, self._end = fd, end

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


class _Partial(OSError):
    """A zero fill that failed after writing up to ``end``."""

    def __init__(self, error: OSError, end: int) -> None:
        super().__init__(error.errno, error.strerror)
        self.error, self.end = error, end


def _zero_fill(fd: int, start: int, size: int) -> int:
    """Write ``size`` zero bytes at ``start`` (short writes continued); the new end. A full
    disk raises :class:`_Partial` with how far the zeros got."""
    zeros = memoryview(bytes(size))
    done = 0
    try:
        while done < size:
            done += os.pwrite(fd, zeros[done:], start + done)
    except OSError as exc:
        raise _Partial(exc, start + done) from None
    return start + done


def start(rt: Any, directory: Path, *, checkpoint_seq: int | None, replay: bool,
          fresh: bool, copies: Copies | None = None,
          preallocate: int = PREALLOCATE) -> Replayed:
    """Start-up of one robot's log: replay what follows the checkpoint (``replay``), then
    attach a new segment to ``rt`` (``rt.wal``). ``copies``: where pairs the log lost may
    still be found (the session logs; :func:`replay_into`); ``preallocate``: its reserve.

    ``checkpoint_seq`` is the checkpoint's ``wal_seq`` (None: no checkpoint, or one written
    without the log; then every record is replayed, from the first ``fresh`` one). A model
    the log cannot rebuild (``fresh``: ``--fresh``, or no checkpoint and no log) starts a new
    history with a ``fresh`` record. After a replay the caller writes a checkpoint (its
    ``wal_seq`` covers every record on disk, including any after a gap).
    """
    rep = (replay_into(rt, directory, -1 if checkpoint_seq is None else checkpoint_seq,
                       copies=copies)
           if replay else Replayed(next_seq=_next_seq(directory)))
    rt.session_resets = 0
    rt.wal = WriteAheadLog(directory, rep.next_seq, preallocate=preallocate)
    if fresh:
        rt.wal.append_fresh()
        rt.wal.commit()
    return rep


def _next_seq(directory: Path) -> int:
    records = read_records(directory)
    return records[-1].seq + 1 if records else 0
