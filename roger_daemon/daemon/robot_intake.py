"""A served robot's intake: pairing by tick, the bounded training queue, re-sent pairs, a full disk.

The mixin of :class:`~roger_daemon.daemon.robot.RobotRuntime` that takes perceptions and actions
(docs/daemon.md). Perception(t) and action(t) meet by tick
(:class:`~roger_daemon.daemon.pairing.Pairing`, windows of ``pair_window`` entries; whichever
arrives first waits). A completed pair goes into the training queue of ``queue_size`` pairs;
when it is full the new pair is dropped, counted in ``dropped``, logged, and shown in status.
An action whose perception never arrives is evicted after ``pair_window`` newer actions and
counted as ``unpaired_actions``. A re-sent copy of the newest pair is counted in ``resent``, not
queued. While the write-ahead log cannot take what would be learned (the disk is full), the
perceptions are counted in ``disk_full_ticks`` instead (docs/durability.md, *Disk full*).

Losses in transport: a skipped perception tick is counted in ``gaps``
(:class:`~roger_daemon.daemon.tick_gaps.TickGaps`, status ``info.lost_in_transport``).
"""

from __future__ import annotations

import logging
from collections import Counter, deque
from typing import Any

import numpy as np

from protocols.messages import Action, Perception
from roger_daemon.daemon.pairing import LEARN_MODES, Pairing
from roger_daemon.daemon.robot_state import Pair
from roger_daemon.daemon.tick_gaps import TickGaps

__all__ = ["RobotIntake"]

log = logging.getLogger("roger_daemon.daemon.robot")  # the runtime's logger, as before the split


class RobotIntake:
    """Intake state and methods of a robot runtime (its ``robot``, ``mode``, ``queue_size`` and
    ``wal`` are the runtime's, and so are ``_label_code`` and ``_dropped``)."""

    robot: str
    mode: str
    queue_size: int
    wal: Any

    def _init_intake(self, robot: str, pair_window: int) -> None:
        """The intake's queue, pairing windows and counters, empty."""
        self.queue: deque[Pair] = deque()
        self.pairing = Pairing(pair_window)
        self.newest: tuple[Perception, int] | None = None  # (message, receipt monotonic ns)
        # counters (restored from checkpoints)
        self.ticks = 0
        self.dropped = 0
        self.unpaired = 0
        self.invalid: Counter[str] = Counter()
        self.last_tick = 0
        self.last_t = 0.0
        self.disk_full_ticks = 0  # perceptions not learned: the disk was full
        self.disk_full_since: int | None = None  # tick learning stopped at (None: learning)
        self.gaps = TickGaps(robot, pair_window)  # perceptions lost in transport
        self._reported: set[str] = set()
        self.resent = 0  # re-sent copies of the newest pair, not learned twice
        # pairs queued by who commanded the action (Action.source: "teacher", "robot", ""),
        # and the teacher's corrections among them (Action.correction; docs/teach.md)
        self.sources: Counter[str] = Counter()
        self.corrections = 0
        self._newest_pair: tuple[int, bytes, bytes] | None = None  # (tick, x, y) bytes

    def _label_code(self, label: str) -> int:
        """The code of ``label`` in the runtime's vocabulary (the runtime defines it)."""
        raise NotImplementedError

    def _dropped(self, tick: int, reason: str) -> None:
        """Report a pair not queued to the runtime's ``decisions`` (the runtime defines it:
        :class:`~roger_daemon.daemon.robot.Decisions` takes the runtime)."""
        raise NotImplementedError

    @property
    def learning(self) -> bool:
        """Whether the robot pairs and learns: its mode does, and its write-ahead log can take
        what it learns (not with the disk full; docs/durability.md, *Disk full*)."""
        return self.mode in LEARN_MODES and (self.wal is None or self.wal.accepting)

    # --- intake --------------------------------------------------------------------------

    def count_invalid(self, reason: str, detail: str) -> None:
        """Count one rejected message; log the first of each reason at WARNING."""
        self.invalid[reason] += 1
        if reason not in self._reported:
            self._reported.add(reason)
            log.warning("%s: rejected message (%s); further ones are only counted", self.robot,
                        detail)
        else:
            log.debug("%s: rejected message (%s)", self.robot, detail)

    def on_perception(self, msg: Perception, recv_ns: int) -> None:
        """Take a perception: count it, keep it as the newest query, pair it when learning."""
        self.ticks += 1
        self.gaps.see(msg.tick)
        self.last_tick, self.last_t = msg.tick, msg.t
        self.newest = (msg, recv_ns)
        if not self.learning:
            if self.mode in LEARN_MODES:
                self._not_logged(msg.tick)
            return
        if self.disk_full_since is not None:
            log.warning("%s: learning resumed at tick %d (%d perceptions not learned while "
                        "the disk was full)", self.robot, msg.tick, self.disk_full_ticks)
            self.disk_full_since = None
        pair = self.pairing.perception(msg)
        if pair is not None:
            self._enqueue(*pair)

    def on_action(self, msg: Action) -> None:
        """Take an action: pair it with its tick's perception when learning."""
        if not self.learning:
            return
        evicted = self.pairing.evicted_actions
        pair = self.pairing.action(msg)
        if pair is not None:
            self._enqueue(*pair)
        elif self.pairing.evicted_actions > evicted:
            self.unpaired += self.pairing.evicted_actions - evicted
            self._warn_once("unpaired", f"{self.robot}: action of tick "
                            f"{self.pairing.last_evicted_action} never met its perception; "
                            "dropped (counted as unpaired_actions)")

    def _not_logged(self, tick: int) -> None:
        """A perception not paired because the log cannot take what would be learned."""
        self.disk_full_ticks += 1
        if self.disk_full_since is None:
            self.disk_full_since = tick
            log.error("%s: learning stopped at tick %d: %s (predictions go on; learning "
                      "resumes by itself when there is space)", self.robot, tick,
                      getattr(self.wal, "full", "") or "the write-ahead log is full")

    def _enqueue(self, perc: Perception, act: Action) -> None:
        key = (act.tick, perc.x.tobytes(), act.y.tobytes())
        if key == self._newest_pair:
            # The sender re-sent the tick it got no answer for (its prediction was lost, or
            # the daemon died after learning the pair): the same pair again is not a new one.
            self.resent += 1
            self._warn_once("resent", f"{self.robot}: pair of tick {act.tick} received again "
                            "(re-sent); not learned twice (counted as info.resent_pairs)")
            self._dropped(act.tick, "resent")
            return
        self._newest_pair = key
        if len(self.queue) >= self.queue_size:
            self.dropped += 1
            self._warn_once("overflow", f"{self.robot}: training queue full ({self.queue_size}); "
                            f"pair of tick {act.tick} dropped (counted in status 'dropped')")
            self._dropped(act.tick, "queue_full")
            return
        self.queue.append(Pair(perc.x, act.y, self._label_code(act.label), act.tick, perc.t))
        self.sources[act.source] += 1
        self.corrections += bool(act.correction)

    def enqueue_recovered(self, x: np.ndarray, y: np.ndarray, label: str, tick: int) -> None:
        """Queue a pair read back from the session log (start-up recovery; no size limit)."""
        self.queue.append(Pair(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64),
                               self._label_code(label), int(tick)))

    def enqueue_pair(self, perc: Perception, act: Action) -> None:
        """Queue the pair ``perc``/``act`` formed elsewhere (a hot standby's pairs at
        takeover, docs/daemon.md): re-sends recognised, the queue bound applied."""
        self._enqueue(perc, act)

    def follow(self, x: np.ndarray, y: np.ndarray, label: str, tick: int) -> None:
        """Queue a pair the serving daemon decided to learn (a hot standby, docs/daemon.md):
        no size limit, and it becomes the newest pair (a re-sent copy is not learned twice)."""
        self.enqueue_recovered(x, y, label, tick)
        self._newest_pair = (int(tick), self.queue[-1].x.tobytes(), self.queue[-1].y.tobytes())

    def _warn_once(self, what: str, text: str) -> None:
        if what not in self._reported:
            self._reported.add(what)
            log.warning("%s; further ones are only counted", text)
        else:
            log.debug(text)
