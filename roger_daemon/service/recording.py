"""The service's session recorders: one per robot, failures counted and never fatal."""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Protocol

from roger_daemon.config import RecordingConfig
from roger_daemon.robot import RobotRuntime

__all__ = ["Recorder", "Recorders"]

log = logging.getLogger(__name__)

_RETENTION_PERIOD_NS = 60 * 1_000_000_000  # recording retention: once a minute


class Recorder(Protocol):
    """The seam to ``roger_daemon.recording.SessionRecorder``."""

    def write(
        self, key: str, payload: bytes, *, log_time_ns: int, publish_time_ns: int, sequence: int
    ) -> None:
        """Record one message."""

    def poll(self, now_ns: int) -> None:
        """Flush or rotate when due (called every loop cycle)."""

    def close(self) -> None:
        """Finish the session's file."""


class Recorders:
    """The recorders of the served robots; an error is logged once per robot, then counted."""

    def __init__(self, recorders: Mapping[str, Recorder], config: RecordingConfig) -> None:
        self.by_robot = dict(recorders)
        self.config = config
        self.errors = 0
        self._failed: set[str] = set()
        self._next_retention = 0  # at the first poll, then every minute

    def __contains__(self, robot: str) -> bool:
        return robot in self.by_robot

    def session_id(self, robot: str) -> str:
        """The session id of ``robot``'s recorder (``""`` without recording)."""
        return str(getattr(self.by_robot.get(robot), "session_id", "") or "")

    def write(self, robot: str, key: str, payload: bytes, log_ns: int, pub_ns: int,
              seq: int) -> None:
        """Record one message of ``robot`` (nothing without a recorder)."""
        rec = self.by_robot.get(robot)
        if rec is None:
            return
        try:
            rec.write(key, payload, log_time_ns=log_ns, publish_time_ns=pub_ns, sequence=seq)
        except Exception as exc:
            self._error(robot, "write", exc)

    def drop(self, rt: RobotRuntime, tick: int, wall_ns: int, reason: str) -> None:
        """Name the pair just not learned in the log, so that replay stays exact.

        ``reason``: ``queue_full``, or ``resent`` (a re-send of the newest pair).
        """
        from roger_daemon.recording.events import dropped_topic, encode_dropped

        payload = encode_dropped(rt.robot, tick, stamp_ns=wall_ns, queue_size=rt.queue_size,
                                 dropped=rt.dropped, reason=reason)
        self.write(rt.robot, dropped_topic(rt.robot), payload, wall_ns, wall_ns, tick)

    def poll(self, monotonic_ns: Callable[[], int]) -> None:
        """Every loop cycle: retention when due, then each recorder's ``poll``."""
        if not self.by_robot:
            return
        now = monotonic_ns()
        if now >= self._next_retention:
            self._next_retention = now + _RETENTION_PERIOD_NS
            self.prune()
        for robot, rec in self.by_robot.items():
            try:
                rec.poll(now)
            except Exception as exc:
                self._error(robot, "poll", exc)

    def prune(self) -> None:
        """Recording retention (``[recording] max_bytes``/``max_age_days``).

        The file being written is kept.
        """
        from roger_daemon.retention import prune_recordings

        r = self.config
        for robot, rec in self.by_robot.items():
            prune_recordings(r.dir, robot, max_bytes=r.max_bytes,
                             max_age_s=r.max_age_days * 86400.0,
                             keep=[Path(p) for p in [getattr(rec, "path", None)] if p])

    def close(self) -> None:
        """Close every recorder (errors counted, never raised)."""
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
