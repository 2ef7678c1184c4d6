"""The service's session recorders: one per robot, failures counted and never fatal; and
each robot's decision log (:class:`DecisionLog`), the decision records of its session."""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Protocol

from protocols import keys
from protocols.decisions import Dropped, Learned, ModelDigest, Reset, chain_digest
from protocols.message_types import Message, encode
from roger_daemon.config import RecordingConfig
from roger_daemon.daemon.checkpoint_meta import CheckpointMeta
from roger_daemon.daemon.robot import Pair, RobotRuntime
from roger_daemon.daemon.service.schedule import QuietWork

__all__ = ["DecisionLog", "Recorder", "Recorders"]

log = logging.getLogger(__name__)

_RETENTION_PERIOD_NS = 60 * 1_000_000_000  # recording retention: once a minute
#: messages wait for a quiet moment at most this long, and at most this many (docs/fleet.md,
#: *Work at quiet moments*)
HOLD_NS = 100_000_000
HOLD_MAX = 2048


class Recorder(Protocol):
    """The seam to ``roger_daemon.recording.SessionRecorder``."""

    def write(
        self, key: str, payload: bytes, *, log_time_ns: int, publish_time_ns: int, sequence: int
    ) -> None:
        """Record one message."""

    def poll(self, now_ns: int) -> bool | None:
        """Flush or rotate when due (called at the loop's quiet moments); true if it did."""

    def close(self) -> None:
        """Finish the session's file."""


class Recorders:
    """The recorders of the served robots; an error is logged once per robot, then counted.

    :meth:`write` holds each message (in order) until the loop's next :meth:`poll` at a quiet
    moment, or until :data:`HOLD_NS` or :data:`HOLD_MAX` is reached: recording then delays no
    answer (docs/fleet.md, *Work at quiet moments*). A message's times are those it was given.
    The recorders' own flushes (a chunk compressed and written) wait for quiet moments too, at
    most one per cycle, or :data:`HOLD_NS`.
    """

    def __init__(self, recorders: Mapping[str, Recorder], config: RecordingConfig) -> None:
        self.by_robot = dict(recorders)
        self.config = config
        self.errors = 0
        self._failed: set[str] = set()
        self._next_retention = 0  # at the first poll, then every minute
        self._held: list[tuple[str, str, bytes, int, int, int]] = []
        self._held_since: int | None = None  # the poll that first saw messages held
        self._flushes = QuietWork(HOLD_NS)  # the recorders' own polls (their flushes)

    def __contains__(self, robot: str) -> bool:
        return robot in self.by_robot

    def session_id(self, robot: str) -> str:
        """The session id of ``robot``'s recorder (``""`` without recording)."""
        return str(getattr(self.by_robot.get(robot), "session_id", "") or "")

    def write(self, robot: str, key: str, payload: bytes, log_ns: int, pub_ns: int,
              seq: int) -> None:
        """Record one message of ``robot`` (nothing without a recorder): held for
        :meth:`poll`."""
        if robot in self.by_robot:
            self._held.append((robot, key, payload, log_ns, pub_ns, seq))

    def write_held(self) -> None:
        """Write every held message into its robot's recorder, in order."""
        held, self._held, self._held_since = self._held, [], None
        for robot, key, payload, log_ns, pub_ns, seq in held:
            try:
                self.by_robot[robot].write(key, payload, log_time_ns=log_ns,
                                           publish_time_ns=pub_ns, sequence=seq)
            except Exception as exc:
                self._error(robot, "write", exc)

    def poll(self, monotonic_ns: Callable[[], int], *, quiet: bool = True) -> None:
        """Every loop cycle: the held messages if ``quiet`` (or held too long or too many),
        retention when due, then, if ``quiet``, the recorders' ``poll`` until one flushes (all
        of them once they waited :data:`HOLD_NS`)."""
        if not self.by_robot:
            return
        now = monotonic_ns()
        if self._held:
            if self._held_since is None:
                self._held_since = now
            if quiet or len(self._held) >= HOLD_MAX or now - self._held_since >= HOLD_NS:
                self.write_held()
        if now >= self._next_retention:
            self._next_retention = now + _RETENTION_PERIOD_NS
            self.prune()
        if not self._flushes.runs(now, quiet):
            return
        for robot, rec in self.by_robot.items():
            try:
                flushed = rec.poll(now)
            except Exception as exc:
                self._error(robot, "poll", exc)
                continue
            if flushed and not self._flushes.overdue:  # the next one's at the next quiet moment
                return

    def prune(self) -> None:
        """Recording retention (``[recording] max_bytes``/``max_age_days``).

        The file being written is kept.
        """
        from roger_daemon.daemon.retention import prune_recordings

        r = self.config
        for robot, rec in self.by_robot.items():
            prune_recordings(r.dir, robot, max_bytes=r.max_bytes,
                             max_age_s=r.max_age_days * 86400.0,
                             keep=[Path(p) for p in [getattr(rec, "path", None)] if p])

    def close(self) -> None:
        """Write the held messages, then close every recorder (errors counted, never
        raised)."""
        self.write_held()
        for robot, rec in self.by_robot.items():
            try:
                rec.close()
            except Exception as exc:
                self._error(robot, "close", exc)

    def _error(self, robot: str, what: str, exc: BaseException) -> None:
        self.errors += 1
        if robot not in self._failed:
            self._failed.add(robot)
            log.error("%s: recorder %s failed: %s (further errors only counted)", robot, what,
                      exc)


class DecisionLog:
    """The decision records of one robot, written into its session log as they are made.

    Attached as ``RobotRuntime.decisions`` (:class:`~roger_daemon.daemon.robot.Decisions`): every
    learned pair, reset and dropped pair; and, from the checkpoint writer, the digest of each
    checkpoint's model chained with the previous one (:mod:`protocols.decisions`). Replay and
    recovery read these instead of re-deriving the decisions (docs/durability.md).
    ``wall_ns`` is the daemon's wall clock (the records' ``stamp_ns`` and log time); the chain
    starts at ``start``, the digest of the model the session started with (its metadata's
    ``start_model_digest``).
    """

    def __init__(self, recorders: Recorders, wall_ns: Callable[[], int], start: str = "") -> None:
        self.recorders = recorders
        self.wall_ns = wall_ns
        self.chain = start  # the newest link of the session's digest chain

    def learned(self, rt: RobotRuntime, pair: Pair) -> None:
        """``pair`` became model pair ``rt.updates - 1``."""
        now = self.wall_ns()
        label = rt.vocab[pair.label] if 0 <= pair.label < len(rt.vocab) else ""
        self._write(rt, "learned", Learned(
            rt.robot, pair.tick, pair.t, updates=rt.updates, segment=rt.session_resets,
            x=pair.x, y=pair.y, label=label, stamp_ns=now), now)

    def reset(self, rt: RobotRuntime, forgotten: int) -> None:
        """The model was replaced by a fresh one."""
        now = self.wall_ns()
        self._write(rt, "reset", Reset(rt.robot, rt.last_tick, rt.last_t,
                                       segment=rt.session_resets, forgotten=forgotten,
                                       stamp_ns=now), now)

    def dropped(self, rt: RobotRuntime, tick: int, reason: str) -> None:
        """The completed pair of ``tick`` was not queued (``queue_full`` or ``resent``)."""
        now = self.wall_ns()
        self._write(rt, "dropped", Dropped(rt.robot, tick, rt.last_t, reason=reason,
                                           queue_size=rt.queue_size, dropped=rt.dropped,
                                           stamp_ns=now), now)

    def checkpoint(self, rt: RobotRuntime, meta: CheckpointMeta) -> None:
        """A checkpoint was written: record its model's digest, chained."""
        self.chain = chain_digest(self.chain, meta.model_digest)
        now = self.wall_ns()
        self._write(rt, "model", ModelDigest(
            rt.robot, int(rt.last_learned_tick or 0), rt.last_t, updates=meta.updates,
            segment=meta.session_segment, digest=meta.model_digest, chain=self.chain,
            stamp_ns=now), now)

    def _write(self, rt: RobotRuntime, event: str, record: Message, now: int) -> None:
        self.recorders.write(rt.robot, keys.decision(rt.robot, event), encode(record), now, now,
                             record.tick)
