"""The status of one served robot: the protocol's fields plus the daemon's ``info`` map.

``info`` holds the loop's timing, learning and prediction times, inbox, checkpoint, write-ahead
log, recording, control confirmation and health (``protocols/README.md``, status).
"""

from __future__ import annotations

import logging
from collections import Counter, deque
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

from protocols.messages import Status
from roger_daemon.daemon.health import LOG_LEVEL_OF
from roger_daemon.daemon.robot import RobotRuntime
from roger_daemon.daemon.window import percentiles

if TYPE_CHECKING:
    from roger_daemon.config import DaemonConfig
    from roger_daemon.daemon.health import Health
    from roger_daemon.daemon.learner_host import Learners
    from roger_daemon.daemon.sdnotify import Notifier
    from roger_daemon.daemon.service.checkpoints import Checkpoints
    from roger_daemon.daemon.service.link import LinkWatch
    from roger_daemon.daemon.service.outbox import Outbox
    from roger_daemon.daemon.service.recording import Recorders
    from roger_daemon.daemon.service.schedule import LoopStats, TickSchedule
    from roger_daemon.transport import Inbox, Transport

__all__ = ["StatusParts", "StatusPublisher", "StatusRound", "disk_full", "invalid_counts"]

log = logging.getLogger(__name__)


def invalid_counts(rt: RobotRuntime, unserved: Mapping[str, int]) -> dict[str, int]:
    """Rejected messages by reason as status and checkpoints report them: the robot's own plus
    ``unserved``, those no served robot can be blamed for (bad keys, unserved robots)."""
    invalid = Counter(rt.invalid)
    invalid.update(unserved)
    return {k: int(v) for k, v in sorted(invalid.items())}


def disk_full(rt: RobotRuntime, checkpoint_error: str) -> str:
    """Which path is full ("" if none): the write-ahead log's, else the checkpoints'."""
    if rt.wal is not None and rt.wal.full:
        return str(rt.wal.full)
    return checkpoint_error if checkpoint_error.startswith("the disk is full") else ""


@dataclass
class StatusRound:
    """One round of status (every robot's, once per status period), published one robot at a
    time: each loop cycle at a quiet moment publishes the next robot's, so that an answer
    that comes meanwhile waits for one robot's status, not for eight (docs/fleet.md,
    *Status one robot at a time*)."""

    due_ns: int = 0  # when the round was due (it is overdue a quarter of a period later)
    pending: deque[RobotRuntime] = field(default_factory=deque)
    timer: dict[str, float] = field(default_factory=dict)  # timer_info, once per round
    lines: list[str] = field(default_factory=list)  # the systemd status line's parts

    def start(self, due_ns: int, robots: Iterable[RobotRuntime], timer: dict[str, float]
              ) -> None:
        """Begin a round: every robot of ``robots`` is to publish its status."""
        self.due_ns, self.timer, self.lines = due_ns, timer, []
        self.pending = deque(robots)



@dataclass(frozen=True)
class StatusParts:
    """What status reads (and publishes through) of the daemon's parts, shared with the
    :class:`~roger_daemon.daemon.service.loop.Service` that owns them."""

    stats: LoopStats
    inbox: Inbox
    schedule: TickSchedule
    learners: Learners
    checkpoints: Checkpoints
    recorders: Recorders
    link: LinkWatch
    health: Mapping[str, Health]
    acks: Mapping[str, tuple[int, str, int]]  # controls.Controls.acks
    resumed: Mapping[str, str]
    unserved: Callable[[], Mapping[str, int]]  # intake.Admission.unserved
    replication_info: Callable[[str], Mapping[str, Any]]  # standby.Replication.info
    transport: Transport
    outbox: Outbox
    notifier: Notifier


class StatusPublisher:
    """The daemon's status: its schedule (once per ``status_hz`` period, after the answers, one
    robot at a time: :class:`StatusRound`) and each robot's message. Built once by the
    :class:`~roger_daemon.daemon.service.loop.Service` with the parts status reads; it owns
    the status schedule (docs/fleet.md, *Status after the answers*)."""

    def __init__(self, config: DaemonConfig, robots: Mapping[str, RobotRuntime], *,
                 parts: StatusParts, timer_active: Callable[[], bool],
                 commit: Callable[[RobotRuntime], None],
                 commit_all: Callable[[Iterable[RobotRuntime]], None]) -> None:
        self.config = config
        self.robots = robots
        self.parts = parts
        self._timer_active = timer_active
        self._commit = commit
        self._commit_all = commit_all
        self.period_ns = int(round(1e9 / config.status_hz))
        self.realtime = config.clock == "realtime"
        self.next_ns = 0  # when the next round is due
        self.round = StatusRound()
        self.started_ns = 0

    def start(self, now: int) -> None:
        """The daemon started at ``now``: uptime counts from it, the first round is due a
        period later."""
        self.started_ns = now
        self.next_ns = now + self.period_ns

    def timer_info(self) -> dict[str, float]:
        """The daemon-wide timer figures every robot's status reports (computed once per round
        of status: each percentile costs a sort of its window)."""
        stats = self.parts.stats
        jitter_p50, jitter_p99 = stats.jitter_ms.pcts(50, 99)
        return {"period_jitter_ms_p50": round(jitter_p50, 4),
                "period_jitter_ms_p99": round(jitter_p99, 4),
                "tick_lateness_ms_p99": round(stats.lateness_ms.pct(99), 4)}

    def robot_status(self, rt: RobotRuntime, now: int,
                     timer: Mapping[str, float] | None = None) -> Status:
        """The status message of ``rt`` at ``now`` (monotonic ns); ``timer``:
        :meth:`timer_info` when the caller computed it already."""
        p, cfg = self.parts, self.config
        ck = p.checkpoints.state[rt.robot]
        invalid = invalid_counts(rt, p.unserved())
        commit_ms = rt.wal.commit_durations() if rt.wal is not None else []  # one copy
        commit_p50, commit_p99 = percentiles(commit_ms, 50, 99)
        learn_p50, learn_p99 = rt.learn_ms.pcts(50, 99)
        latency_p50, latency_p99 = rt.latency.pcts(50, 99)
        info: dict[str, Any] = {
            "clock": cfg.clock,
            "rate_hz": cfg.rate_hz,
            **(self.timer_info() if timer is None else timer),
            "missed_ticks": p.stats.missed_ticks,
            "learn_ms_p50": round(learn_p50, 4),
            "learn_ms_p99": round(learn_p99, 4),
            "predict_ms_p50": round(rt.predict_ms.pct(50), 4),
            "unpaired_actions": rt.unpaired,
            "learn_errors": rt.learn_errors,
            "predict_errors": rt.predict_errors,
            "inbox_overflow": p.inbox.overflow,
            "inbox_depth": len(p.inbox),
            "labels": len(rt.vocab),
            "checkpoint": ck.path,
            "checkpoint_updates": ck.updates,
            "checkpoint_digest": ck.digest,
            "checkpoints_written": ck.written,
            "checkpoint_errors": ck.errors,
            "checkpoint_error": ck.error,
            "resumed_from": p.resumed.get(rt.robot, ""),
            "recovered_pairs": rt.recovered_pairs,
            "recovery": rt.recovery,
            "recovery_lost_pairs": rt.recovery_lost,
            "disk_full": disk_full(rt, ck.error),
            "disk_full_ticks": rt.disk_full_ticks,
            "learning_stopped": rt.disk_full_since is not None,
            "lost_in_transport": rt.gaps.lost,
            **p.link.info(now),
            "last_learned_tick": -1 if rt.last_learned_tick is None else rt.last_learned_tick,
            "recording": rt.robot in p.recorders,
            "recording_errors": p.recorders.errors,
            "wal": rt.wal is not None,
            "wal_commits": 0 if rt.wal is None else rt.wal.commits,
            "wal_commit_ms_p50": round(commit_p50, 4),
            "wal_commit_ms_p99": round(commit_p99, 4),
            "wal_commit_ms_max": 0.0 if rt.wal is None else round(rt.wal.commit_ms_max, 3),
            "resent_pairs": rt.resent,
            "pairs_teacher": rt.sources["teacher"],
            "pairs_robot": rt.sources["robot"],
            "corrections": rt.corrections,
            "workers": "inline",
            "controls": p.acks[rt.robot][0],
            "control_op": p.acks[rt.robot][1],
            "control_stamp_ns": p.acks[rt.robot][2],
            "level": p.health[rt.robot].last[0],
            "level_reasons": p.health[rt.robot].last[1],
            **p.replication_info(rt.robot),
        }
        info.update(p.learners.info(rt))
        return Status(
            rt.robot, rt.last_tick, rt.last_t, daemon=cfg.id, mode=rt.mode,
            ticks=rt.ticks, updates=rt.updates, updates_per_s=rt.updates_per_s(now),
            experts=int(rt.model.n_experts), queue_depth=len(rt.queue), dropped=rt.dropped,
            invalid=dict(invalid), latency_ms_p50=latency_p50,
            latency_ms_p99=latency_p99, uptime_s=(now - self.started_ns) / 1e9,
            info=info,
        )

    def _overdue_ns(self) -> int:
        """When the status due (or the round under way) may wait no longer: a quarter of its
        period after it was due."""
        due = self.round.due_ns if self.round.pending else self.next_ns
        return due + self.period_ns // 4

    def due(self, now: int) -> bool:
        """Whether status goes out now: once due, and while a round is under way, at a moment
        when it delays no answer (in realtime the first quarter of a period after a tick, in
        lockstep while no prediction is being answered); in any case a quarter of its own
        period after it was due (docs/fleet.md, *Status after the answers*)."""
        if not self.round.pending and now < self.next_ns:
            return False
        return now >= self._overdue_ns() or self.quiet_moment(now)

    def quiet_moment(self, now: int) -> bool:
        """Whether work done now delays no answer: in realtime the first quarter of a period
        after a tick, once the tick's predictions are delivered (with learner workers: the
        delivery window, :mod:`..tick_windows`); in lockstep while no prediction is being
        answered and nothing waits in the inbox (the status round; the loop's held recordings
        and collections, docs/fleet.md)."""
        p = self.parts
        if self.realtime and self._timer_active():
            if p.learners.delivering():
                return False
            return now < p.schedule.next_tick - 3 * p.schedule.period_ns // 4
        return not p.learners.answering() and len(p.inbox) == 0

    def deadline(self, now: int) -> int:
        """When the loop must wake for status: when it is due; due and held back, when it can
        be held no longer (the answers it waits for wake the loop anyway); with a round under
        way, now if this is a quiet moment (the next robot's status), else when it is
        overdue."""
        if self.round.pending:
            return now if self.quiet_moment(now) else self._overdue_ns()
        if self.next_ns > now:
            return self.next_ns
        return self._overdue_ns()

    def publish(self, now: int) -> None:
        """The next robot's status of the round, starting a round when none is under way
        (:class:`StatusRound`); every robot's left once the round is overdue. A robot's log is
        committed before its status reports it; its health level is assessed (a change is
        logged); the systemd status line follows the round's last robot."""
        rnd = self.round
        if not rnd.pending:
            self.watch_links(now)
            rnd.start(self.next_ns, self.robots.values(), self.timer_info())
            self.next_ns += self.period_ns
            if self.next_ns <= now:
                self.next_ns = now + self.period_ns
        overdue = now >= self._overdue_ns()
        if overdue:  # the rest at once: their logs committed side by side first, as one was
            self._commit_all(rnd.pending)
        while rnd.pending:
            rnd.lines.append(self._publish_one(rnd.pending.popleft(), now, rnd.timer))
            if not overdue:
                break
        if not rnd.pending:
            self.parts.notifier.status("; ".join(rnd.lines))

    def watch_links(self, now: int) -> None:
        """At a round's start: the links' events since the previous round, and whether the
        loop stalled (:class:`~roger_daemon.daemon.service.link.LinkWatch`). After an outage or
        a stall the latency windows start afresh; after an outage each robot's health says its
        WARN/ERROR again (``roger_daemon.daemon.health``; a stalled loop published nothing
        meanwhile, and what it says next goes out on a live link)."""
        p = self.parts
        returned = p.link.apply(p.transport.link_events())
        stalled = p.link.round(now, self.period_ns) > 0
        if returned or stalled:
            for rt in self.robots.values():
                rt.latency.values.clear()
        since = p.link.outage_began_ns
        if returned and since is not None:
            for rt in self.robots.values():
                p.health[rt.robot].link_returned(since)

    def _publish_one(self, rt: RobotRuntime, now: int, timer: Mapping[str, float]) -> str:
        """Publish ``rt``'s status (its log committed first); its part of the systemd line."""
        self._commit(rt)
        st = self.robot_status(rt, now, timer)
        health = self.parts.health[rt.robot]
        before = health.last[0]
        level, reasons = health.assess(st.to_map(), now)
        if level != before:  # into the journal too: journalctl -p warning shows it
            log.log(LOG_LEVEL_OF[level], "%s: status %s%s", rt.robot, level,
                    f" ({reasons})" if reasons else "")
        st = replace(st, info={**st.info, "level": level, "level_reasons": reasons})
        self.parts.outbox.status(rt.robot, st)
        return (f"{rt.robot}: {st.mode}, {st.updates} updates ({st.updates_per_s:.1f}/s), "
                f"{st.experts} experts, queue {st.queue_depth}, dropped {st.dropped}, "
                f"p99 {st.latency_ms_p99:.1f} ms, {level}")
