"""Where the robots' models live, as the service loop sees it: one interface, two hosts.

The loop (:class:`~roger_daemon.daemon.service.loop.Service`) calls only :class:`Learners`;
it never asks which host it has. :class:`InlineLearners` keeps the models in the loop's own
thread (``[daemon] workers = "inline"``); :class:`~roger_daemon.daemon.learners.ProcessLearners`
keeps them in learner worker processes (``"process"``; docs/fleet.md). Both answer a
perception with :meth:`RobotRuntime.answer <roger_daemon.daemon.robot.RobotRuntime.answer>`'s
reply, which they hand to :attr:`Replies.publish` (the one publish path, which commits the
robots' write-ahead logs first: acknowledged means durable, docs/durability.md), and a model's
state for a checkpoint to :attr:`Replies.write_snapshot`. What differs is only *when*: inline at
once on the loop's thread, a worker when its reply arrives (:meth:`Learners.pump`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from protocols.messages import Perception
from roger_daemon.daemon.robot import Pair, RobotRuntime

__all__ = ["Answer", "InlineLearners", "Learners", "Replies", "answer_of", "log_seq"]

_MS = 1_000_000

#: One prediction to publish: (runtime, ``RobotRuntime.answer``'s reply, the perception, its
#: receipt in monotonic ns, the write-ahead log record its model state reflects).
Answer = tuple[RobotRuntime, dict[str, Any], Perception, int, int]


class SnapshotWriter(Protocol):
    """Checkpoint ``rt``, with the model state a worker sent (``None``: the loop's own)."""

    def __call__(self, rt: RobotRuntime, reason: str,
                 model_state: Mapping[str, np.ndarray] | None, *,
                 ahead: Sequence[Pair] = (), sync: bool = False) -> None:
        """Write the checkpoint."""


@dataclass(frozen=True)
class Replies:
    """Where the learners' results go (the service's two entry points, nothing more)."""

    publish: Callable[[Sequence[Answer]], None]
    write_snapshot: SnapshotWriter
    period_ns: int  # the realtime tick's period


def log_seq(rt: RobotRuntime) -> int:
    """The last write-ahead log record of ``rt`` (-1 without a log)."""
    return rt.wal.last_seq if rt.wal is not None else -1


def answer_of(rt: RobotRuntime, perc: Perception, recv_ns: int) -> Answer:
    """``rt``'s answer to ``perc`` computed now, on this thread. A prediction only reads the
    model: any failure is a failed reply (counted when published), never a stopped loop."""
    try:
        reply = rt.answer(perc)
    except Exception as exc:
        reply = {"ok": False, "error": f"{type(exc).__name__}: {exc}"}
    return (rt, reply, perc, recv_ns, log_seq(rt))


class Learners(Protocol):
    """What the service loop needs from wherever the models live (see the module docstring).

    Times are the loop's monotonic ns; ``deadline_ns`` is the next realtime tick while the
    timer is active, else ``None``."""

    #: predictions are prepared as perceptions arrive and the tick publishes the newest
    #: prepared ones, so the loop fires a due tick before anything else (docs/fleet.md,
    #: *Prepared predictions*)
    prepares: bool
    #: the models are the loop's own ``RobotRuntime.model`` objects (not in worker processes),
    #: so a state can be installed into them in place (a standby's catch-up, docs/daemon.md)
    in_process: bool

    def attach(self, replies: Replies) -> None:
        """Send results to ``replies`` from now on (the service's start)."""

    def fds(self) -> Sequence[int]:
        """File descriptors the loop's wait includes (worker pipes)."""

    def has_work(self, now: int, deadline_ns: int | None) -> bool:
        """Whether the loop must not wait: a pair can be learned now, or replies are in."""

    def pump(self, deadline_ns: int | None = None) -> None:
        """Handle the replies that arrived and keep the workers fed."""

    def learn(self, now: int, deadline_ns: int | None) -> None:
        """Learn one queued pair on the loop's thread if it fits before ``deadline_ns``."""

    def learn_more(self) -> None:
        """Shutdown: one more step of learning what is queued."""

    def wake_ns(self) -> int | None:
        """When the loop must wake for the learners (a delivery window closing)."""

    def learn_all(self, rt: RobotRuntime) -> None:
        """Learn (or send) every queued pair of ``rt``, ahead of anything after it."""

    def predict(self, rt: RobotRuntime, perc: Perception, recv_ns: int) -> None:
        """Lockstep: answer ``perc`` now (inline) or when the worker replies."""

    def prepare(self, rt: RobotRuntime, perc: Perception, recv_ns: int) -> None:
        """Realtime: ``perc`` arrived; prepare its prediction for the next tick."""

    def publish_tick(self, due: Sequence[RobotRuntime]) -> bool:
        """The realtime tick: publish a prediction for the newest perception of each of
        ``due``; whether any was published."""

    def new_tick(self, deadline_ns: int, *, published: bool = True) -> None:
        """The tick fired; the next one is at ``deadline_ns``."""

    def snapshot(self, rt: RobotRuntime, reason: str, *, sync: bool) -> None:
        """Checkpoint ``rt``'s model (through :attr:`Replies.write_snapshot`)."""

    def drain(self, rt: RobotRuntime | None = None) -> None:
        """Wait until every request sent (for ``rt``, or all) is answered and bookkept."""

    def answering(self) -> bool:
        """Whether a prediction is being computed elsewhere (a worker)."""

    def delivering(self) -> bool:
        """Whether the last tick's predictions are still being delivered."""

    def learning(self) -> bool:
        """Whether learning is in flight elsewhere (a worker)."""

    def info(self, rt: RobotRuntime) -> dict[str, Any]:
        """The host's part of ``rt``'s status ``info``."""

    def close(self, *, kill: bool = False) -> None:
        """Release the host (workers stopped, or killed when ``kill``)."""


class InlineLearners:
    """The models in the loop's own thread: it learns one pair per cycle when that fits before
    the next realtime tick (or nothing was learned since the last one, so learning always
    progresses), round robin over the robots, and answers at once."""

    prepares = False
    in_process = True

    def __init__(self, robots: Mapping[str, RobotRuntime]) -> None:
        self._robots = list(robots.values())
        self._replies: Replies | None = None
        self._learned_since_tick = False
        self._learn_est_ns = 0
        self._rr = 0

    def attach(self, replies: Replies) -> None:
        """Send results to ``replies``."""
        self._replies = replies

    def _sink(self) -> Replies:
        if self._replies is None:
            raise RuntimeError("InlineLearners used before attach")
        return self._replies

    def fds(self) -> Sequence[int]:
        """None: the loop waits on its inbox alone."""
        return ()

    def has_work(self, now: int, deadline_ns: int | None) -> bool:
        """Whether a queued pair can be learned now (:meth:`learn`)."""
        if not any(rt.learning and rt.queue for rt in self._robots):
            return False
        if deadline_ns is None or not self._learned_since_tick:
            return True
        return now + self._learn_est_ns + _MS < deadline_ns

    def pump(self, deadline_ns: int | None = None) -> None:
        """Nothing arrives from elsewhere."""

    def learn(self, now: int, deadline_ns: int | None) -> None:
        """Learn one queued pair if it fits (:meth:`has_work`)."""
        if self.has_work(now, deadline_ns):
            self.learn_more()

    def learn_more(self) -> None:
        """Learn the next robot's queued pair (round robin); its time estimates the next."""
        robots = self._robots
        for i in range(len(robots)):
            rt = robots[(self._rr + i) % len(robots)]
            if rt.learning and rt.queue:
                self._rr = (self._rr + i + 1) % len(robots)
                ns = int(rt.learn_one() * _MS)
                self._learn_est_ns = max(ns, int(self._learn_est_ns * 0.95))
                self._learned_since_tick = True
                return

    def wake_ns(self) -> int | None:
        """No window of its own."""
        return None

    def learn_all(self, rt: RobotRuntime) -> None:
        """Learn every queued pair of ``rt`` now."""
        while rt.learning and rt.queue:
            rt.learn_one()

    def predict(self, rt: RobotRuntime, perc: Perception, recv_ns: int) -> None:
        """Answer ``perc`` now."""
        self._sink().publish([answer_of(rt, perc, recv_ns)])

    def prepare(self, rt: RobotRuntime, perc: Perception, recv_ns: int) -> None:
        """Nothing ahead: the tick computes the predictions of the newest perceptions."""

    def publish_tick(self, due: Sequence[RobotRuntime]) -> bool:
        """Compute the tick's predictions now and publish them together."""
        batch = [answer_of(rt, *rt.newest) for rt in due if rt.newest is not None]
        if batch:
            self._sink().publish(batch)
        return bool(batch)

    def new_tick(self, deadline_ns: int, *, published: bool = True) -> None:
        """Every robot may learn once more before the next tick."""
        self._learned_since_tick = False

    def snapshot(self, rt: RobotRuntime, reason: str, *, sync: bool) -> None:
        """Checkpoint the loop's own model of ``rt``."""
        self._sink().write_snapshot(rt, reason, None, sync=sync)

    def drain(self, rt: RobotRuntime | None = None) -> None:
        """Nothing is in flight."""

    def answering(self) -> bool:
        """Never: answers are computed on the loop's thread."""
        return False

    def delivering(self) -> bool:
        """Never: the tick publishes what it computes."""
        return False

    def learning(self) -> bool:
        """Never in flight: learning runs on the loop's thread."""
        return False

    def info(self, rt: RobotRuntime) -> dict[str, Any]:
        """Nothing beyond the loop's own (``workers`` is ``"inline"``)."""
        return {}

    def close(self, *, kill: bool = False) -> None:
        """Nothing to release."""
