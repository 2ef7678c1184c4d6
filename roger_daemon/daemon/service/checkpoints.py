"""Checkpoints of the served robots: when they are due, writing them, rotating the WAL.

A checkpoint is a copy of one robot's arrays (:func:`checkpoint_snapshot`) written by a
background thread (:class:`Checkpoints`; on the loop thread in unit tests). After a durable
checkpoint the robot's write-ahead log starts a new segment and drops the segments the previous
checkpoint covers.
"""

from __future__ import annotations

import errno
import logging
from collections import deque
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from roger_daemon.config import CheckpointConfig
from roger_daemon.daemon.checkpoint import CheckpointMeta, write_checkpoint
from roger_daemon.daemon.robot import Pair, RobotRuntime
from roger_daemon.daemon.service.clock import Clock
from roger_daemon.daemon.service.schedule import QuietWork

__all__ = ["CheckpointState", "Checkpoints", "Snapshot", "checkpoint_snapshot"]

log = logging.getLogger(__name__)

#: periodic checkpoints wait for a quiet moment at most this long (Checkpoints.poll)
_OVERDUE_NS = 1_000_000_000
#: after a failed checkpoint the next attempt waits this long, doubled at each failure up to
#: :data:`_RETRY_MAX_NS`; the same failure is logged again at most that often
#: (docs/durability.md, *Disk full*)
_RETRY_NS = 1_000_000_000
_RETRY_MAX_NS = 60_000_000_000

#: (model arrays, daemon arrays, metadata) of one robot
Snapshot = tuple[dict[str, np.ndarray], dict[str, np.ndarray], CheckpointMeta]


def checkpoint_snapshot(
    rt: RobotRuntime, reason: str, *, daemon_id: str, created_unix_ns: int,
    session_id: str, session_segment: int, invalid: Mapping[str, int] | None = None,
    recovered_pairs: int = 0, recovered_from: Sequence[str] = (),
    model_state: Mapping[str, np.ndarray] | None = None, ahead: Sequence[Pair] = (),
) -> Snapshot:
    """(model arrays, daemon arrays, metadata) of one robot, copied (safe to write later).

    ``model_state``: the model's ``state_dict`` when a worker process sent it (else it is
    taken from ``rt.model``); ``ahead``: pairs in flight to that worker, saved queued;
    ``invalid``: the rejections its counters report (status's: the robot's own and those no
    robot can be blamed for; by default the robot's own).

    ``session_id``/``session_segment`` say where in the session logs the model stands (the
    recorder's session and the number of resets in it; ``""`` without recording): start-up
    recovery reads the log tail from there (with ``counters.last_learned_tick`` to check it).
    """
    if model_state is None:
        model = {k: np.array(v, copy=True) for k, v in rt.model.state_dict().items()}
    else:  # a worker's state: already this snapshot's own arrays
        model = dict(model_state)
    meta = CheckpointMeta(
        reason=reason, updates=rt.updates, x_dim=rt.dims.x, y_dim=rt.dims.y,
        created_unix_ns=created_unix_ns, daemon=daemon_id, counters=rt.counters(invalid),
        session_id=session_id, session_segment=session_segment,
        wal_seq=None if rt.wal is None else rt.wal.last_seq, learner=rt.learner,
        recovered_pairs=recovered_pairs, recovered_from=tuple(recovered_from))
    return model, rt.daemon_arrays(ahead), meta


@dataclass
class CheckpointState:
    """One robot's checkpoint bookkeeping (shown in its status)."""

    generation: int = 0
    time_ns: int = 0
    path: str = ""
    updates: int = 0
    digest: str = ""
    written: int = 0
    errors: int = 0
    in_flight: Future[tuple[Path, CheckpointMeta]] | None = None
    in_flight_gen: int = 0
    #: ``wal_seq`` of the newest checkpoints written in this life, oldest first: the log is
    #: kept back to the oldest of them (a fallback for checkpoints found unreadable)
    wal_seqs: deque[int] = field(default_factory=deque)
    #: the last failure ("" once a checkpoint is written again), when the next attempt may
    #: come, how long that wait is, and ``errors`` at the last success
    error: str = ""
    retry_ns: int = 0
    backoff_ns: int = 0
    errors_before: int = 0
    #: the first periodic checkpoint comes this share of its interval early (robot i of n:
    #: i/n), so that the robots' checkpoints do not all fall due together
    phase: float = 0.0


class Checkpoints:
    """When each robot's checkpoint is due, and writing it (``sync``: on the caller's thread).

    ``snapshot(rt, reason, model_state, ahead)`` copies what a checkpoint holds;
    ``written(rt, meta)`` is told of every checkpoint written (on the loop thread).
    """

    def __init__(
        self, config: CheckpointConfig, robots: Mapping[str, RobotRuntime], clock: Clock,
        snapshot: Callable[[RobotRuntime, str, Mapping[str, np.ndarray] | None,
                            Sequence[Pair]], Snapshot],
        *, sync: bool,
        written: Callable[[RobotRuntime, CheckpointMeta], None] | None = None,
    ) -> None:
        self.config = config
        self.robots = robots
        self.clock = clock
        self._snapshot = snapshot
        self._sync = sync
        self._written = written
        self.state = {r: CheckpointState() for r in robots}
        self._writer: ThreadPoolExecutor | None = None
        self._periodic = QuietWork(_OVERDUE_NS)  # when poll takes and books them
        #: set at shutdown: a failure from then on means the final checkpoints failed
        self.stopping = False
        self.final_ok = True

    def start(self, now: int) -> None:
        """The models as loaded count as checkpointed; start the writer thread. Robot ``i``
        of ``n`` takes its first periodic checkpoint ``i/n`` of an interval early (docs/fleet.md,
        *Checkpoints one at a time*)."""
        for i, rt in enumerate(self.robots.values()):
            st = self.state[rt.robot]
            st.generation, st.time_ns, st.updates = rt.generation, now, rt.updates
            st.phase = i / len(self.robots)
        if not self._sync:
            self._writer = ThreadPoolExecutor(max_workers=1, thread_name_prefix="roger-ckpt")

    def due(self, now: int) -> Iterator[RobotRuntime]:
        """The robots whose periodic checkpoint is due (none in flight, something learned)."""
        c = self.config
        for rt in self.robots.values():
            st = self.state[rt.robot]
            if st.in_flight is not None or rt.generation == st.generation:
                continue
            if now < st.retry_ns:  # the last one failed: not at every cycle
                continue
            early = 1.0 - st.phase
            by_updates = c.every_updates > 0 and \
                rt.generation - st.generation >= c.every_updates * early
            by_time = c.every_s > 0 and now - st.time_ns >= c.every_s * 1e9 * early
            if by_updates or by_time:
                yield rt

    def poll(self, now: int, quiet: bool, take: Callable[[RobotRuntime], None]) -> None:
        """Once per loop cycle: at a quiet moment, ``take`` the periodic checkpoint of at most
        one robot that is due, then book at most one finished write (which starts a new
        write-ahead log segment: several file syncs); at any moment once a second has passed
        since the last quiet one, all of them (docs/fleet.md, *Checkpoints one at a time*)."""
        if not self._periodic.runs(now, quiet):
            return
        overdue = self._periodic.overdue
        for rt in self.due(now):
            take(rt)
            if not overdue:
                break
        self.collect(most=None if overdue else 1)

    def up_to_date(self, rt: RobotRuntime) -> bool:
        """Whether the newest checkpoint holds everything ``rt`` learned and queued."""
        return rt.generation == self.state[rt.robot].generation and not rt.queue

    def write(self, rt: RobotRuntime, reason: str,
              model_state: Mapping[str, np.ndarray] | None, *,
              ahead: Sequence[Pair] = (), sync: bool = False) -> None:
        """Checkpoint ``rt`` (with the model state a worker sent, if given)."""
        st = self.state[rt.robot]
        model, daemon, meta = self._snapshot(rt, reason, model_state, ahead)
        c = self.config
        st.time_ns = self.clock.monotonic_ns()
        gen = rt.generation
        if sync or self._writer is None:
            if st.in_flight is not None:
                self.collect(wait=True)
            try:
                path, full = write_checkpoint(c.dir, rt.robot, model, daemon, meta, **c.limits())
            except Exception as exc:
                self._failed(rt.robot, exc)
                return
            self._done(rt.robot, gen, path, full)
            return
        if st.in_flight is not None:
            return
        st.in_flight = self._writer.submit(
            write_checkpoint, c.dir, rt.robot, model, daemon, meta, **c.limits()
        )
        st.in_flight_gen = gen

    def collect(self, wait: bool = False, most: int | None = None) -> None:
        """Book the background writes that finished (``wait``: all of them; at most ``most``
        of them)."""
        for robot, st in self.state.items():
            fut = st.in_flight
            if fut is None or not (wait or fut.done()):
                continue
            if most is not None:
                if most <= 0:
                    return
                most -= 1
            st.in_flight = None
            try:
                path, meta = fut.result()
            except Exception as exc:
                self._failed(robot, exc)
                continue
            self._done(robot, st.in_flight_gen, path, meta)

    def close(self) -> None:
        """Wait for the writer thread to finish."""
        if self._writer is not None:
            self._writer.shutdown(wait=True)

    def _rotate_wal(self, robot: str, meta: CheckpointMeta) -> None:
        """After a durable checkpoint: new log segment; drop the segments that the oldest of
        the ``keep`` newest checkpoints covers (at least the previous one: the log then
        reaches back to every checkpoint kept, in case the newer ones turn out unreadable)."""
        rt = self.robots[robot]
        st = self.state[robot]
        if rt.wal is None or meta.wal_seq is None:
            return
        rt.wal.rotate()
        st.wal_seqs.append(meta.wal_seq)
        if len(st.wal_seqs) > max(2, self.config.keep):
            st.wal_seqs.popleft()
        if len(st.wal_seqs) >= max(2, self.config.keep):
            rt.wal.prune(st.wal_seqs[0])

    def _done(self, robot: str, gen: int, path: Path, meta: CheckpointMeta) -> None:
        st = self.state[robot]
        self._rotate_wal(robot, meta)
        st.generation, st.path, st.updates = gen, str(path), meta.updates
        st.phase = 0.0  # only the first periodic checkpoint comes early
        st.digest = meta.model_digest
        st.written += 1
        if st.error:
            log.warning("%s: checkpoints are written again (%s)", robot, path)
        st.error, st.retry_ns, st.backoff_ns, st.errors_before = "", 0, 0, st.errors
        if self._written is not None:
            self._written(self.robots[robot], meta)
        log.info("%s: checkpoint %s written (%s, %d updates, model %s)", robot, path,
                 meta.reason, st.updates, st.digest[:12])

    def _failed(self, robot: str, exc: BaseException) -> None:
        """Count a failed checkpoint; the next attempt waits (1 s, doubled at each failure up
        to a minute), so that a lasting failure (a full disk) is tried and logged at most
        once a minute, not at every loop cycle."""
        st = self.state[robot]
        st.errors += 1
        if self.stopping:
            self.final_ok = False
        full = isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT)
        st.error = f"the disk is full at {self.config.dir} ({exc})" if full else str(exc)
        st.backoff_ns = min(2 * st.backoff_ns or _RETRY_NS, _RETRY_MAX_NS)
        st.retry_ns = self.clock.monotonic_ns() + st.backoff_ns
        log.error("%s: checkpoint failed (%d in a row): %s; next attempt in %g s", robot,
                  st.errors - st.errors_before, st.error, st.backoff_ns / 1e9)
