"""The daemon's way out: orderly shutdown, or abort after an error in the loop.

Shutdown: STOPPING=1, undeclare subscribers, drain the inbox, learn what is queued for up to
``checkpoint.shutdown_learn_s``, write the final checkpoints (still-queued pairs are saved in
them and learned after a restart), close recorders and the session. These functions are parts
of :class:`~roger_daemon.daemon.service.loop.Service` and use its state.
"""

from __future__ import annotations

import logging
import time
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from roger_daemon.daemon.service.loop import Service

__all__ = ["abort", "shutdown"]

log = logging.getLogger(__name__)


def shutdown(svc: Service) -> None:
    """Stop intake, drain, learn what fits, checkpoint, close recorders and transport."""
    if svc._stopping:
        return
    svc._stopping = True
    svc.checkpoints.stopping = True
    t0 = time.monotonic()
    svc.notifier.stopping("shutting down: draining and checkpointing")
    log.info("shutting down: stopping intake")
    try:
        svc.transport.stop_intake()
        item = svc.inbox.get(0)
        while item is not None:
            svc._handle(item)
            item = svc.inbox.get(0)
        _learn_queued(svc, t0 + svc.config.checkpoint.shutdown_learn_s)
        svc.checkpoints.collect(wait=True)
        if svc.config.checkpoint.on_shutdown:
            for rt in svc.robots.values():
                if not svc.checkpoints.up_to_date(rt):
                    svc._checkpoint(rt, "shutdown", sync=True)
                else:
                    log.info("%s: checkpoint %s is up to date", rt.robot,
                             svc.checkpoints.state[rt.robot].path or "(none: nothing learned)")
        queued = sum(len(rt.queue) for rt in svc.robots.values())
        if queued:
            log.info("%d queued pairs not learned before shutdown%s", queued,
                     "; saved in the checkpoint" if svc.config.checkpoint.on_shutdown
                     else "; LOST (checkpoint.on_shutdown = false)")
    finally:
        _release(svc, aborting=False)
        log.info("shut down in %.2f s", time.monotonic() - t0)


def abort(svc: Service) -> None:
    """Close everything without checkpointing (after an unexpected error in the loop)."""
    svc._stopping = True
    svc.notifier.stopping("aborting after an error")
    svc.checkpoints.stopping = True
    _release(svc, aborting=True)


def _release(svc: Service, *, aborting: bool) -> None:
    """Close, in order: checkpoint writer, learner workers (killed when ``aborting``), the
    write-ahead log committer (not when ``aborting``: a commit may hang), the write-ahead
    logs, recorders, transport."""
    svc.checkpoints.close()
    svc.learners.close(kill=aborting)
    if svc._committer is not None and not aborting:
        svc._committer.shutdown(wait=True)
    _close_wals(svc)
    svc.recorders.close()
    svc.transport.close()
    svc.inbox.close()


def _learn_queued(svc: Service, until: float) -> None:
    """Shutdown: learn queued pairs until ``until`` (``time.monotonic``); then wait for every
    pair in flight (learned and logged) and every snapshot (with workers)."""
    while time.monotonic() < until and any(
        rt.learning and rt.queue for rt in svc.robots.values()
    ):
        svc.learners.learn_more()
    svc.learners.drain()


def _close_wals(svc: Service) -> None:
    for rt in svc.robots.values():
        if rt.wal is not None:
            try:
                rt.wal.close()
            except OSError as exc:
                log.error("%s: closing the write-ahead log failed: %s", rt.robot, exc)
