"""The service loop: one thread owns every model; timers are events of the same loop.

Each cycle of :meth:`Service.step`:

1. wait on the :class:`~roger_daemon.transport.Inbox` until the next deadline (at most
   ``max_wait_s``; zero when there is learning to do), then drain what is there: decode,
   validate, count rejects by reason, record, route (perception, action, control);
   in lockstep mode each perception is answered as it is admitted, after learning its
   robot's pairs already complete (so prediction(t+1) includes pair t when action(t) came
   first, and no pair that came after it);
2. realtime mode: if the 30 Hz deadline has passed, publish a prediction for the newest
   perception of every predicting robot and measure the period;
3. learn one queued pair (round robin over robots) if the estimated learning time fits before
   the next deadline, or nothing was learned since the last tick (so learning always
   progresses);
4. status at ``status_hz``, periodic checkpoints (written by a background thread from copied
   arrays), recorder ``poll``, systemd watchdog ping.

The parts, one module each: :mod:`.intake` (admission and rejects), :mod:`.answers`
(predictions), :mod:`.schedule` (the realtime tick), :mod:`.status`, :mod:`.outbox`
(publishing), :mod:`.checkpoints`, :mod:`.recording` and :mod:`.shutdown`.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from protocols import keys
from protocols.messages import (
    Action,
    Control,
    Perception,
    Status,
)
from roger_daemon.config import DaemonConfig
from roger_daemon.daemon.checkpoint_meta import CheckpointMeta
from roger_daemon.daemon.gc_policy import Thresholds, collect_when_idle
from roger_daemon.daemon.health import Health
from roger_daemon.daemon.learner_host import InlineLearners, Learners, Replies
from roger_daemon.daemon.robot import Pair, RobotRuntime
from roger_daemon.daemon.sdnotify import Notifier
from roger_daemon.daemon.service.answers import Answers
from roger_daemon.daemon.service.checkpoints import Checkpoints, Snapshot, checkpoint_snapshot
from roger_daemon.daemon.service.clock import Clock, RealClock
from roger_daemon.daemon.service.controls import Controls
from roger_daemon.daemon.service.intake import Admission
from roger_daemon.daemon.service.link import LinkWatch
from roger_daemon.daemon.service.outbox import Outbox
from roger_daemon.daemon.service.recording import DecisionLog, Recorder, Recorders
from roger_daemon.daemon.service.schedule import LoopStats, TickSchedule
from roger_daemon.daemon.service.shutdown import Shutdown
from roger_daemon.daemon.service.status import StatusParts, StatusPublisher, invalid_counts
from roger_daemon.daemon.standby import Replication
from roger_daemon.transport import Inbox, Incoming, Transport

__all__ = ["Service"]

log = logging.getLogger(__name__)

_MS = 1_000_000
MAX_DRAIN_PER_STEP = 512  # inbox items handled per loop cycle


class Service:
    """The daemon's loop over one transport and a set of robots.

    Parameters
    ----------
    config
        The validated configuration.
    transport
        Zenoh, or :class:`~roger_daemon.testing.MemoryTransport` in unit tests.
    robots
        One :class:`RobotRuntime` per served robot, models already loaded or resumed.
    notifier
        systemd notify; a no-op one is used when ``None``.
    recorders
        Per robot id, an object with ``write``/``poll``/``close`` (optional).
    clock
        Time sources (a fake in unit tests).
    sync_checkpoints
        Write checkpoints on the loop thread (unit tests) instead of the writer thread.
    resumed
        Per robot id, the checkpoint path it resumed from (shown in status).
    """

    def __init__(
        self,
        config: DaemonConfig,
        transport: Transport,
        robots: Mapping[str, RobotRuntime],
        *,
        notifier: Notifier | None = None,
        recorders: Mapping[str, Recorder] | None = None,
        clock: Clock | None = None,
        sync_checkpoints: bool = False,
        resumed: Mapping[str, str] | None = None,
        learners: Learners | None = None,
    ) -> None:
        self.config = config
        self.transport = transport
        self.robots = dict(robots)
        self.notifier = notifier or Notifier(None)
        self.recorders = Recorders(recorders or {}, config.recording)
        self.admission = Admission(self.robots, self.recorders,
                                   count_unserved=config.count_unserved)
        self.clock: Clock = clock or RealClock()
        for rt in self.robots.values():  # the decision records of each recorded session
            rec = self.recorders.by_robot.get(rt.robot)
            start = dict(getattr(rec, "metadata", {})).get("start_model_digest", "")
            rt.decisions = (DecisionLog(self.recorders, self.clock.time_ns, start)
                            if rec is not None else None)
        self.inbox = Inbox(max(4 * config.queue_size, 1024))
        self.stats = LoopStats()
        self.resumed = dict(resumed or {})
        self.checkpoints = Checkpoints(config.checkpoint, self.robots, self.clock, self._snapshot,
                                       sync=sync_checkpoints, written=self._checkpoint_written)
        self.outbox = Outbox(self.recorders, self.clock)
        self.answers = Answers(self.outbox, self.clock, self.stats, self._commit_all)
        self.schedule = TickSchedule(int(round(1e9 / config.rate_hz)), self.stats)
        self._commit_ns = int(config.checkpoint.wal_commit_ms * _MS)
        self._realtime = config.clock == "realtime"
        self._stop = False
        #: set once started (gc_policy.hold_collections): collect at quiet moments only
        self.gc_thresholds: Thresholds | None = None
        # where the models live (learner_host.Learners): the loop's own thread, or worker
        # processes (roger_daemon.daemon.learners.ProcessLearners)
        self.learners: Learners = learners or InlineLearners(self.robots)
        self._committer: ThreadPoolExecutor | None = None
        self.health = {r: Health() for r in self.robots}
        self.link = LinkWatch()  # links up and down, the loop's stalls (status info)
        self.controls = Controls(self.robots, self.learners, self._checkpoint, self.outbox,
                                 self.clock, self.status_of)
        # per robot: (controls applied, op of the last one, its stamp_ns) -- the confirmation
        self.acks = self.controls.acks
        #: which robots this daemon serves and which it follows (docs/daemon.md, Hot standby)
        self.replication = Replication(self)
        #: the status schedule and messages (status.StatusPublisher)
        self.status = StatusPublisher(
            config, self.robots, timer_active=self._timer_active, commit=self._commit,
            commit_all=self._commit_all, parts=StatusParts(
                stats=self.stats, inbox=self.inbox, schedule=self.schedule,
                learners=self.learners, checkpoints=self.checkpoints,
                recorders=self.recorders, link=self.link, health=self.health,
                acks=self.acks, resumed=self.resumed, unserved=lambda: self.unserved,
                replication_info=self.replication.info, transport=self.transport,
                outbox=self.outbox, notifier=self.notifier))
        #: the way out (shutdown.Shutdown); ``stopping`` once it began
        self.closer = Shutdown(
            config.checkpoint, self.robots, notifier=self.notifier, transport=transport,
            inbox=self.inbox, checkpoints=self.checkpoints, learners=self.learners,
            recorders=self.recorders, handle=self._handle,
            checkpoint=lambda rt, reason: self._checkpoint(rt, reason, sync=True),
            committer=lambda: self._committer)

    # --- life cycle ----------------------------------------------------------------------

    def start(self) -> None:
        """Declare publishers, subscribers and the liveliness token; then READY=1."""
        now = self.clock.monotonic_ns()
        self.status.start(now)
        self.outbox.declare(self.transport, self.robots)
        # One subscriber (one callback thread) for everything: samples from one sender keep
        # their order (action(t) before perception(t+1)), which lockstep determinism needs.
        self.transport.subscribe(keys.everything(), self.inbox.put)
        self.transport.declare_token(keys.daemon_liveliness(self.config.id))
        self.replication.start(now)
        self.checkpoints.start(now)
        self.learners.attach(Replies(self.answers.publish, self.write_snapshot,
                                     self.schedule.period_ns))
        for rt in self.robots.values():  # an append's age is judged on the loop's clock
            if rt.wal is not None:
                rt.wal.clock = self.clock.monotonic_ns
        if self.robots:  # fdatasync releases the GIL: the logs commit side by side, and early
            self._committer = ThreadPoolExecutor(max_workers=min(8, len(self.robots)),
                                                 thread_name_prefix="roger-wal")
        self.schedule.start(now)
        for rt in self.robots.values():  # the baseline that health changes are judged from
            self.health[rt.robot].assess(self.status_of(rt, now).to_map(), now)
        summary = ", ".join(
            f"{r.robot} ({r.mode}, {r.updates} updates)" for r in self.robots.values()
        )
        log.info("daemon %s ready: %s clock at %g Hz, serving %s", self.config.id,
                 self.config.clock, self.config.rate_hz, summary)
        self.notifier.ready(f"serving {summary}")

    def request_stop(self) -> None:
        """Ask the loop to stop (safe from a signal handler: it only sets a flag)."""
        self._stop = True

    @property
    def stop_requested(self) -> bool:
        """Whether :meth:`request_stop` was called."""
        return self._stop

    def run(self, max_wait_s: float = 0.05) -> None:
        """Run cycles until :meth:`request_stop`; then :meth:`shutdown`."""
        try:
            while not self._stop:
                self.step(max_wait_s)
        except BaseException:
            self.abort()
            raise
        self.shutdown()

    def abort(self) -> None:
        """Close everything without checkpointing (after an unexpected error in the loop)."""
        self.closer.abort()

    @property
    def final_checkpoints_ok(self) -> bool:
        """Whether every checkpoint attempted during shutdown was written."""
        return self.checkpoints.final_ok

    @property
    def unserved(self) -> Counter[str]:
        """Rejections no served robot can be blamed for (bad keys, unserved robots)."""
        return self.admission.unserved

    # --- one cycle -------------------------------------------------------------------------

    def step(self, max_wait_s: float = 0.05) -> None:
        """One cycle of the loop (see the module docstring)."""
        now = self.clock.monotonic_ns()
        if self.learners.has_work(now, self._tick_deadline()):
            wait = 0.0
        else:
            wait = max(0.0, min(max_wait_s, (self._next_deadline(now) - now) / 1e9))
        # one wait for messages, worker replies and the next deadline (docs/fleet.md, One wait)
        item = self.inbox.get(wait, self.learners.fds())
        # bounded, so that a backlog (lockstep runs ahead of learning) never starves status,
        # checkpoints, the watchdog or a stop request: the rest waits for the next cycle
        budget = min(self.inbox.capacity, MAX_DRAIN_PER_STEP)
        while item is not None and budget > 0:
            self._tick_first()
            self._handle(item)
            budget -= 1
            item = self.inbox.get(0) if budget > 0 else None
        self._tick_first()
        self.learners.pump(self._tick_deadline())
        now = self.clock.monotonic_ns()
        if self._realtime and now >= self.schedule.next_tick:
            self._on_timer(now)
            now = self.clock.monotonic_ns()
        self.learners.learn(now, self._tick_deadline())
        now = self.clock.monotonic_ns()
        self.replication.poll(now)
        if self.status.due(now):  # one robot's at a time (status.StatusRound)
            self.status.publish(now)
        for rt in self.robots.values():
            if rt.wal is not None:  # due: now; else started in the background (docs/durability)
                rt.wal.commit_early(now, self._commit_ns, self._committer)
                rt.wal.poll_space(now)  # a full disk: space again? (docs/durability.md)
        # work that can wait for a quiet moment (docs/fleet.md, *Work at quiet moments*)
        quiet = self.status.quiet_moment(self.clock.monotonic_ns())
        self.checkpoints.poll(now, quiet, lambda rt: self._checkpoint(rt, "periodic"))
        self.recorders.poll(self.clock.monotonic_ns, quiet=quiet)
        self.notifier.watchdog(now)
        if quiet and self.gc_thresholds is not None:
            collect_when_idle(self.gc_thresholds)

    def _tick_first(self) -> None:
        """When the learners prepare predictions (workers) the tick publishes them: fire it as
        soon as it is due, before the messages and replies that arrived meanwhile (nothing
        drained now could be ready for it; docs/fleet.md, *Prepared predictions*)."""
        if self.learners.prepares and self._realtime:
            now = self.clock.monotonic_ns()
            if now >= self.schedule.next_tick:
                self._on_timer(now)

    def _on_timer(self, now: int) -> None:
        """Realtime tick: publish a prediction for the newest perception of every predicting
        robot (inline computed now; workers prepared them as the perceptions arrived:
        docs/fleet.md, *Prepared predictions*)."""
        due = [rt for rt in self.robots.values()
               if rt.predicting and rt.newest is not None and not self.closer.stopping]
        published = self.learners.publish_tick(due)
        self.schedule.fired(now, bool(due))
        self.learners.new_tick(self.schedule.next_tick, published=published)

    def _next_deadline(self, now: int) -> int:
        deadline = self.status.deadline(now)
        if self._realtime and self._timer_active():
            deadline = min(deadline, self.schedule.next_tick)
        wake = self.learners.wake_ns()
        return deadline if wake is None else min(deadline, wake)  # the delivery window

    def _timer_active(self) -> bool:
        return any(rt.predicting and rt.newest is not None for rt in self.robots.values())

    def _tick_deadline(self) -> int | None:
        """The next realtime tick while the timer is active (learning must fit before it)."""
        return self.schedule.next_tick if self._realtime and self._timer_active() else None

    # --- intake ----------------------------------------------------------------------------

    def _handle(self, item: Incoming) -> None:
        if self.replication.intercept(item):  # tokens and decision records (standby.py)
            return
        admitted = self.admission.admit(item)
        if admitted is None:
            return
        rt, _, msg = admitted
        if self.replication.passive(rt.robot):  # another daemon serves it: follow only
            self.replication.take(rt, msg, item.recv_ns)
        elif isinstance(msg, Perception):
            rt.on_perception(msg, item.recv_ns)
            if rt.predicting and not self.closer.stopping:
                if not self._realtime:  # lockstep: its complete pairs learned first, so
                    # prediction(t+1) includes pair t when action(t) came first (and no pair
                    # that came after it: the causal order of a lock-stepped simulator)
                    self.learners.learn_all(rt)
                    self.learners.predict(rt, msg, item.recv_ns)
                else:  # published on the next tick (prepared now by workers)
                    self.learners.prepare(rt, msg, item.recv_ns)
        elif isinstance(msg, Action):
            rt.on_action(msg)
        elif isinstance(msg, Control):
            self.controls.apply(rt, msg)

    # --- output ----------------------------------------------------------------------------

    # --- status ----------------------------------------------------------------------------

    def status_of(self, rt: RobotRuntime, now: int) -> Status:
        """The status message of one robot at ``now`` (monotonic ns)."""
        return self.status.robot_status(rt, now)

    # --- checkpoints and recording ---------------------------------------------------------

    def _snapshot(self, rt: RobotRuntime, reason: str,
                  model_state: Mapping[str, np.ndarray] | None = None,
                  ahead: Sequence[Pair] = ()) -> Snapshot:
        # the same counts as status (restored into rt.invalid; self.unserved restarts at 0)
        return checkpoint_snapshot(
            rt, reason, daemon_id=self.config.id, created_unix_ns=self.clock.time_ns(),
            session_id=self.recorders.session_id(rt.robot),
            session_segment=rt.session_resets, invalid=invalid_counts(rt, self.unserved),
            model_state=model_state, ahead=ahead,
        )

    def _checkpoint(self, rt: RobotRuntime, reason: str, *, sync: bool = False) -> None:
        self.learners.snapshot(rt, reason, sync=sync)  # the model's state to write_snapshot

    def write_snapshot(self, rt: RobotRuntime, reason: str,
                       model_state: Mapping[str, np.ndarray] | None, *,
                       ahead: Sequence[Pair] = (), sync: bool = False) -> None:
        """Checkpoint ``rt`` (with the model state a worker sent, if given)."""
        self.checkpoints.write(rt, reason, model_state, ahead=ahead, sync=sync)

    def _checkpoint_written(self, rt: RobotRuntime, meta: CheckpointMeta) -> None:
        """A checkpoint of ``rt`` is on disk: its model digest goes into the session log."""
        decisions = getattr(rt.decisions, "inner", rt.decisions)  # standby.Replicated's
        if isinstance(decisions, DecisionLog):
            decisions.checkpoint(rt, meta)

    def _commit(self, rt: RobotRuntime) -> None:
        """Group commit of the robot's write-ahead log (a no-op when nothing is pending).

        A failed commit stops the daemon: it may no longer acknowledge anything.
        """
        if rt.wal is None or not rt.wal.dirty:
            return
        rt.wal.commit()

    def _commit_all(self, robots: Iterable[RobotRuntime]) -> None:
        """Commit the dirty logs of ``robots`` side by side (one ``fdatasync`` each, in
        parallel), before answering several robots at once."""
        dirty = [rt.wal for rt in robots if rt.wal is not None and rt.wal.dirty]
        if len(dirty) > 1 and self._committer is not None:
            list(self._committer.map(lambda w: w.commit(), dirty))
        else:
            for w in dirty:
                w.commit()

    # --- shutdown --------------------------------------------------------------------------

    def shutdown(self) -> None:
        """Stop intake, drain, learn what fits, checkpoint, close recorders and transport."""
        self.closer.shutdown()
