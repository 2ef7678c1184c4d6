"""A robot's control requests (``mode``, ``reset``, ``checkpoint``; protocols/README.md,
*control*), applied by the service loop and confirmed at once with a status."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from protocols.messages import Control
from roger_daemon.daemon.robot import RobotRuntime

if TYPE_CHECKING:
    from roger_daemon.daemon.service.loop import Service

__all__ = ["apply_control"]

log = logging.getLogger(__name__)


def apply_control(svc: Service, rt: RobotRuntime, msg: Control) -> None:
    """Apply ``msg`` to ``rt``, then publish ``rt``'s status carrying the request's stamp."""
    if msg.op == "mode":
        if msg.mode != rt.mode:
            log.info("%s: mode %s -> %s", rt.robot, rt.mode, msg.mode)
        rt.mode = msg.mode
    elif msg.op == "reset":
        learn_before_reset(svc, rt)
        log.info("%s: reset requested: forgetting %d learned pairs", rt.robot, rt.updates)
        rt.reset()
    elif msg.op == "checkpoint":
        log.info("%s: checkpoint requested", rt.robot)
        svc._checkpoint(rt, "requested")
    n = svc.acks[rt.robot][0] + 1
    svc.acks[rt.robot] = (n, msg.op, msg.stamp_ns)
    # confirm at once: a status carrying this control's stamp (protocols/README.md, control)
    now = svc.clock.monotonic_ns()
    svc.outbox.status(rt.robot, svc.status_of(rt, now))


def learn_before_reset(svc: Service, rt: RobotRuntime) -> None:
    """Learn and log every pair queued before a reset; the reset then forgets them with the
    model. Which pairs the old model learned depends only on the order in which the messages
    arrived, not on how far the loop had got (docs/fleet.md, *Ordering is the guarantee*)."""
    svc.learners.learn_all(rt)
    svc.learners.drain(rt)  # a worker's pending replies are bookkept and logged first
