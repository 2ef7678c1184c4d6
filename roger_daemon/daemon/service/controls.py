"""A robot's control requests (``mode``, ``reset``, ``checkpoint``; protocols/README.md,
*control*), applied by the service loop and confirmed at once with a status."""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable

from protocols.messages import Control, Status
from roger_daemon.daemon.learner_host import Learners
from roger_daemon.daemon.robot import RobotRuntime
from roger_daemon.daemon.service.clock import Clock
from roger_daemon.daemon.service.outbox import Outbox

__all__ = ["Controls"]

log = logging.getLogger(__name__)


class Controls:
    """Apply control requests and confirm each with a status carrying its stamp.

    ``acks`` holds, per robot, (controls applied, op of the last one, its ``stamp_ns``): the
    confirmation status reports."""

    def __init__(self, robots: Iterable[str], learners: Learners,
                 checkpoint: Callable[[RobotRuntime, str], None], outbox: Outbox, clock: Clock,
                 status_of: Callable[[RobotRuntime, int], Status]) -> None:
        self.acks: dict[str, tuple[int, str, int]] = {r: (0, "", 0) for r in robots}
        self._learners, self._checkpoint = learners, checkpoint
        self._outbox, self._clock, self._status_of = outbox, clock, status_of

    def apply(self, rt: RobotRuntime, msg: Control) -> None:
        """Apply ``msg`` to ``rt``, then publish ``rt``'s status carrying the request's
        stamp."""
        if msg.op == "mode":
            if msg.mode != rt.mode:
                log.info("%s: mode %s -> %s", rt.robot, rt.mode, msg.mode)
            rt.mode = msg.mode
        elif msg.op == "reset":
            self.learn_before_reset(rt)
            log.info("%s: reset requested: forgetting %d learned pairs", rt.robot, rt.updates)
            rt.reset()
        elif msg.op == "checkpoint":
            log.info("%s: checkpoint requested", rt.robot)
            self._checkpoint(rt, "requested")
        n = self.acks[rt.robot][0] + 1
        self.acks[rt.robot] = (n, msg.op, msg.stamp_ns)
        # confirm at once: a status carrying this control's stamp (protocols/README.md)
        now = self._clock.monotonic_ns()
        self._outbox.status(rt.robot, self._status_of(rt, now))

    def learn_before_reset(self, rt: RobotRuntime) -> None:
        """Learn and log every pair queued before a reset; the reset then forgets them with
        the model. Which pairs the old model learned depends only on the order in which the
        messages arrived, not on how far the loop had got (docs/fleet.md, *Ordering is the
        guarantee*)."""
        self._learners.learn_all(rt)
        self._learners.drain(rt)  # a worker's pending replies are bookkept and logged first
