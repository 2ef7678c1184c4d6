"""The daemon's way out: orderly shutdown, or abort after an error in the loop.

Shutdown: STOPPING=1, undeclare subscribers, drain the inbox, learn what is queued for up to
``checkpoint.shutdown_learn_s``, write the final checkpoints (still-queued pairs are saved in
them and learned after a restart), close recorders and the session. :class:`Shutdown` is built
once by :class:`~roger_daemon.daemon.service.loop.Service` with the parts it closes.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING

from roger_daemon.daemon.robot import RobotRuntime

if TYPE_CHECKING:
    from roger_daemon.config import CheckpointConfig
    from roger_daemon.daemon.learner_host import Learners
    from roger_daemon.daemon.sdnotify import Notifier
    from roger_daemon.daemon.service.checkpoints import Checkpoints
    from roger_daemon.daemon.service.recording import Recorders
    from roger_daemon.transport import Inbox, Incoming, Transport

__all__ = ["Shutdown"]

log = logging.getLogger(__name__)


class Shutdown:
    """The service's shutdown and abort (module doc); ``stopping`` once either began.

    ``handle``: the loop's intake of one item (the inbox drained at shutdown);
    ``checkpoint``: a robot's checkpoint taken through the learners; ``committer``: the
    write-ahead logs' commit pool, once started.
    """

    def __init__(self, config: CheckpointConfig, robots: Mapping[str, RobotRuntime], *,
                 notifier: Notifier, transport: Transport, inbox: Inbox,
                 checkpoints: Checkpoints, learners: Learners, recorders: Recorders,
                 handle: Callable[[Incoming], None],
                 checkpoint: Callable[[RobotRuntime, str], None],
                 committer: Callable[[], ThreadPoolExecutor | None]) -> None:
        self.config = config
        self.robots = robots
        self.notifier, self.transport, self.inbox = notifier, transport, inbox
        self.checkpoints, self.learners, self.recorders = checkpoints, learners, recorders
        self._handle, self._checkpoint, self._committer = handle, checkpoint, committer
        self.stopping = False

    def shutdown(self) -> None:
        """Stop intake, drain, learn what fits, checkpoint, close recorders and transport."""
        if self.stopping:
            return
        self.stopping = True
        self.checkpoints.stopping = True
        t0 = time.monotonic()
        self.notifier.stopping("shutting down: draining and checkpointing")
        log.info("shutting down: stopping intake")
        try:
            self.transport.stop_intake()
            item = self.inbox.get(0)
            while item is not None:
                self._handle(item)
                item = self.inbox.get(0)
            self._learn_queued(t0 + self.config.shutdown_learn_s)
            self.checkpoints.collect(wait=True)
            if self.config.on_shutdown:
                self._final_checkpoints()
            queued = sum(len(rt.queue) for rt in self.robots.values())
            if queued:
                log.info("%d queued pairs not learned before shutdown%s", queued,
                         "; saved in the checkpoint" if self.config.on_shutdown
                         else "; LOST (checkpoint.on_shutdown = false)")
        finally:
            self._release(aborting=False)
            log.info("shut down in %.2f s", time.monotonic() - t0)

    def abort(self) -> None:
        """Close everything without checkpointing (after an unexpected error in the loop)."""
        self.stopping = True
        self.notifier.stopping("aborting after an error")
        self.checkpoints.stopping = True
        self._release(aborting=True)

    def _final_checkpoints(self) -> None:
        for rt in self.robots.values():
            if not self.checkpoints.up_to_date(rt):
                self._checkpoint(rt, "shutdown")
            else:
                log.info("%s: checkpoint %s is up to date", rt.robot,
                         self.checkpoints.state[rt.robot].path or "(none: nothing learned)")

    def _release(self, *, aborting: bool) -> None:
        """Close, in order: checkpoint writer, learner workers (killed when ``aborting``), the
        write-ahead log committer (not when ``aborting``: a commit may hang), the write-ahead
        logs, recorders, transport."""
        self.checkpoints.close()
        self.learners.close(kill=aborting)
        committer = self._committer()
        if committer is not None and not aborting:
            committer.shutdown(wait=True)
        self._close_wals()
        self.recorders.close()
        self.transport.close()
        self.inbox.close()

    def _learn_queued(self, until: float) -> None:
        """Shutdown: learn queued pairs until ``until`` (``time.monotonic``); then wait for
        every pair in flight (learned and logged) and every snapshot (with workers)."""
        while time.monotonic() < until and any(
            rt.learning and rt.queue for rt in self.robots.values()
        ):
            self.learners.learn_more()
        self.learners.drain()

    def _close_wals(self) -> None:
        for rt in self.robots.values():
            if rt.wal is not None:
                try:
                    rt.wal.close()
                except OSError as exc:
                    log.error("%s: closing the write-ahead log failed: %s", rt.robot, exc)
