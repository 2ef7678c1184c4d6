"""Answering perceptions with predictions: lockstep at once, realtime on the clock's tick.

Inline, the loop's thread predicts after committing the robot's write-ahead log (a prediction
acknowledges what it reports); with learner worker processes the worker predicts and the loop
publishes its replies (:func:`worker_predictions`). Either way the answer is
:meth:`~roger_daemon.daemon.robot.RobotRuntime.answer`'s one encoding, published by
:func:`publish_reply`. These functions are parts of
:class:`~roger_daemon.daemon.service.loop.Service`'s loop and use its state.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from protocols.messages import Perception, stamp_prediction
from roger_daemon.daemon.robot import RobotRuntime

if TYPE_CHECKING:
    from roger_daemon.daemon.service.loop import Service

__all__ = ["answer_now", "learn_queued", "on_timer", "publish_prediction", "publish_reply",
           "worker_predictions"]

log = logging.getLogger(__name__)


def answer_now(svc: Service, rt: RobotRuntime, perc: Perception, recv_ns: int) -> None:
    """Lockstep: learn every complete pair of ``rt`` first, then answer ``perc``, as soon as
    it is admitted (in arrival order, before the loop takes in the next message).

    So prediction(t+1) includes pair t whenever action(t) arrived before perception(t+1),
    which is the causal order of a lock-stepped simulator (deterministic runs), and never a
    pair that arrived after it. With learner workers the robot's worker starts on the request
    while the loop takes in the other robots' messages (docs/fleet.md, *Requests as
    perceptions arrive*)."""
    learn_queued(svc, rt)
    publish_prediction(svc, rt, perc, recv_ns)


def learn_queued(svc: Service, rt: RobotRuntime) -> None:
    """Learn every pair queued for ``rt`` (while its mode learns): inline now, or sent to its
    learner worker, ahead of anything sent after (before an answer, before a reset)."""
    if svc.learners is not None:
        svc.learners.learn_all(rt)
    while rt.learning and rt.queue:
        rt.learn_one()


def publish_prediction(svc: Service, rt: RobotRuntime, perc: Perception, recv_ns: int) -> None:
    """Answer ``perc``: inline (WAL committed first), or by the robot's learner worker."""
    if svc.learners is not None:  # answered in worker_predictions
        svc.learners.predict(rt, perc, recv_ns)
        return
    svc._commit(rt)  # acknowledged means durable: the updates it reports are on disk
    try:
        reply = rt.answer(perc)
    except Exception as exc:  # prediction only reads the model: skip it, keep serving
        reply = {"ok": False, "error": f"{type(exc).__name__}: {exc}"}
    publish_reply(svc, rt, reply, perc, recv_ns)


def worker_predictions(svc: Service, batch: Sequence[tuple[Any, ...]]) -> None:
    """Publish predictions learner workers computed: ``(rt, reply, perception, receipt ns,
    log seq)`` each. Every pair one counts was bookkept (logged up to ``log seq``) before its
    reply arrived: commit the logs not yet durable that far (in parallel), then publish."""
    svc._commit_all({id(b[0]): b[0] for b in batch
                     if b[0].wal is not None and b[0].wal.durable_seq < b[4]}.values())
    for rt, reply, perc, recv_ns, _seq in batch:
        publish_reply(svc, rt, reply, perc, recv_ns)


def publish_reply(svc: Service, rt: RobotRuntime, reply: dict[str, Any], perc: Perception,
                  recv_ns: int) -> None:
    """Publish the answer to ``perc`` (:meth:`RobotRuntime.answer`'s reply, computed inline
    or by a learner worker): the one way the daemon publishes a prediction. A failed one is
    counted (and logged the first time)."""
    if not reply.get("ok"):
        rt.predict_errors += 1
        if rt.predict_errors == 1:
            log.error("%s: prediction for tick %d failed (%s); further failures are only "
                      "counted", rt.robot, perc.tick, reply.get("error"))
        return
    latency_ms = (svc.clock.monotonic_ns() - recv_ns) / 1e6
    rt.predict_ms.add(float(reply["ms"]))
    rt.latency.add(latency_ms)
    # RobotRuntime.answer encoded the Prediction: set the publish-time fields in place instead
    # of decoding and encoding it again (the loop's largest cost per robot; docs/fleet.md)
    stamp_ns = svc.clock.time_ns()
    payload = stamp_prediction(reply["pred"], robot=rt.robot, tick=perc.tick,
                               latency_ms=latency_ms, mode=rt.mode, stamp_ns=stamp_ns)
    svc.outbox.prediction(rt.robot, payload, stamp_ns, perc.tick)
    svc.stats.published += 1


def on_timer(svc: Service, now: int) -> None:
    """Realtime tick: publish a prediction for the newest perception of every predicting
    robot. Inline the loop computes them now; learner workers prepared them as the
    perceptions arrived (``ProcessLearners.prepare``), and the tick publishes the newest
    prepared ones at once (docs/fleet.md, *Prepared predictions*)."""
    due = [rt for rt in svc.robots.values()
           if rt.predicting and rt.newest is not None and not svc._stopping]
    batch = []
    if svc.learners is not None:
        batch = svc.learners.prepared(due)
        if batch:
            worker_predictions(svc, batch)
    else:  # inline: commit the robots' logs side by side, then predict
        svc._commit_all(rt for rt in svc.robots.values() if rt.predicting)
        for rt in due:
            perc, recv_ns = rt.newest  # type: ignore[misc]
            publish_prediction(svc, rt, perc, recv_ns)
    svc._learned_since_tick = False
    svc.schedule.fired(now, bool(due))
    if svc.learners is not None:  # the delivery window if it published
        svc.learners.new_tick(svc.schedule.next_tick, published=bool(batch))
