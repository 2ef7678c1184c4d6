"""Publishing the learners' answers: the one way the daemon publishes a prediction.

Wherever the models live (:mod:`roger_daemon.daemon.learner_host`), an answer is
:meth:`~roger_daemon.daemon.robot.RobotRuntime.answer`'s reply: the prediction encoded once
(``encode_prediction``), with its publish-time fields stamped here (``stamp_prediction``).
Every pair an answer counts was logged before it was computed: the logs not yet durable that
far are committed first, side by side (acknowledged means durable, docs/durability.md).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

from protocols.messages import Perception, stamp_prediction
from roger_daemon.daemon.learner_host import Answer
from roger_daemon.daemon.robot import RobotRuntime
from roger_daemon.daemon.service.clock import Clock
from roger_daemon.daemon.service.outbox import Outbox
from roger_daemon.daemon.service.schedule import LoopStats

__all__ = ["Answers"]

log = logging.getLogger(__name__)


@dataclass
class Answers:
    """Commit, stamp, publish and record the learners' answers (the service's
    :attr:`~.learner_host.Replies.publish`)."""

    outbox: Outbox
    clock: Clock
    stats: LoopStats
    #: commits the dirty write-ahead logs of the robots given, in parallel
    commit_all: Callable[[Iterable[RobotRuntime]], None]

    def publish(self, batch: Sequence[Answer]) -> None:
        """Publish ``(rt, reply, perception, receipt ns, log seq)`` each: first commit the
        logs not yet durable up to ``log seq`` (in parallel), then publish in order."""
        self.commit_all({id(b[0]): b[0] for b in batch
                         if b[0].wal is not None and b[0].wal.durable_seq < b[4]}.values())
        for rt, reply, perc, recv_ns, _seq in batch:
            self._publish_one(rt, reply, perc, recv_ns)

    def _publish_one(self, rt: RobotRuntime, reply: dict[str, Any], perc: Perception,
                     recv_ns: int) -> None:
        """Publish one answer; a failed one is counted (and logged the first time)."""
        if not reply.get("ok"):
            rt.predict_errors += 1
            if rt.predict_errors == 1:
                log.error("%s: prediction for tick %d failed (%s); further failures are only "
                          "counted", rt.robot, perc.tick, reply.get("error"))
            return
        latency_ms = (self.clock.monotonic_ns() - recv_ns) / 1e6
        rt.predict_ms.add(float(reply["ms"]))
        rt.add_latency(recv_ns, latency_ms)  # once per perception (docs/zenoh-notes.md §8)
        # RobotRuntime.answer encoded the Prediction: set the publish-time fields in place
        # instead of decoding and encoding it again (the loop's largest cost per robot;
        # docs/fleet.md)
        stamp_ns = self.clock.time_ns()
        payload = stamp_prediction(reply["pred"], robot=rt.robot, tick=perc.tick,
                                   latency_ms=latency_ms, mode=rt.mode, stamp_ns=stamp_ns)
        self.outbox.prediction(rt.robot, payload, stamp_ns, perc.tick)
        self.stats.published += 1
