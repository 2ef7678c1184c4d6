"""The service loop: one thread owns every model; timers are events of the same loop.

Each cycle of :meth:`Service.step`:

1. wait on the :class:`~roger_daemon.transport.Inbox` until the next deadline (at most
   ``max_wait_s``; zero when there is learning to do), then drain what is there: decode,
   validate, count rejects by reason, record, route (perception, action, control);
   in lockstep mode every perception drained is answered at once, after learning the pairs
   already complete (so prediction(t+1) includes pair t when action(t) came first);
2. realtime mode: if the 30 Hz deadline has passed, publish a prediction for the newest
   perception of every predicting robot and measure the period;
3. learn one queued pair (round robin over robots) if the estimated learning time fits before
   the next deadline, or nothing was learned since the last tick (so learning always
   progresses);
4. status at ``status_hz``, periodic checkpoints (written by a background thread from copied
   arrays), recorder ``poll``, systemd watchdog ping.

Shutdown (:meth:`Service.shutdown`): STOPPING=1, undeclare subscribers, drain the inbox,
learn what is queued for up to ``checkpoint.shutdown_learn_s``, write the final checkpoints
(still-queued pairs are saved in them and learned after a restart), close recorders and the
session.
"""

from __future__ import annotations

import logging
import time
from collections import Counter
from collections.abc import Callable, Mapping
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from protocols import keys
from protocols.errors import ProtocolError
from protocols.messages import (
    MAX_PAYLOAD_BYTES,
    Action,
    Control,
    Message,
    Perception,
    Status,
    decode,
    encode,
)
from roger_daemon.checkpoint import write_checkpoint
from roger_daemon.config import DaemonConfig
from roger_daemon.health import LOG_LEVEL_OF, Health
from roger_daemon.robot import RobotRuntime, _Window
from roger_daemon.sdnotify import Notifier
from roger_daemon.transport import Inbox, Incoming, Publisher, Transport

__all__ = ["Clock", "Recorder", "Service", "checkpoint_snapshot"]

log = logging.getLogger(__name__)

INPUT_KINDS = ("perception", "action", "control")
RECORD_ONLY_KINDS = ("command", "episode")
_MS = 1_000_000
MAX_DRAIN_PER_STEP = 512  # inbox items handled per loop cycle


class Clock(Protocol):
    """Time sources: ``monotonic_ns`` for deadlines and latency, ``time_ns`` for stamps."""

    def monotonic_ns(self) -> int: ...

    def time_ns(self) -> int: ...


class _RealClock:
    monotonic_ns = staticmethod(time.monotonic_ns)
    time_ns = staticmethod(time.time_ns)


def checkpoint_snapshot(
    rt: RobotRuntime, reason: str, *, daemon_id: str, created_unix_ns: int,
    session_id: str, session_segment: int, extra: dict[str, Any] | None = None,
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict[str, Any]]:
    """(model arrays, daemon arrays, metadata) of one robot, copied (safe to write later).

    ``session_id``/``session_segment`` say where in the session logs the model stands (the
    recorder's session and the number of resets in it; ``""`` without recording): start-up
    recovery reads the log tail from there (with ``counters.last_learned_tick`` to check it).
    """
    model = {k: np.array(v, copy=True) for k, v in rt.model.state_dict().items()}
    meta: dict[str, Any] = {
        "created_unix_ns": created_unix_ns,
        "reason": reason,
        "daemon": daemon_id,
        "updates": rt.updates,
        "x_dim": rt.dims.x,
        "y_dim": rt.dims.y,
        "counters": rt.counters(),
        "session_id": session_id,
        "session_segment": session_segment,
    }
    if extra:
        meta.update(extra)
    return model, rt.daemon_arrays(), meta


class Recorder(Protocol):
    """The seam to ``roger_daemon.recording.SessionRecorder``."""

    def write(
        self, key: str, payload: bytes, *, log_time_ns: int, publish_time_ns: int, sequence: int
    ) -> None: ...

    def poll(self, now_ns: int) -> None: ...

    def close(self) -> None: ...


@dataclass
class _CheckpointState:
    generation: int = 0
    time_ns: int = 0
    path: str = ""
    updates: int = 0
    digest: str = ""
    written: int = 0
    errors: int = 0
    in_flight: Future[tuple[Path, dict[str, Any]]] | None = None
    in_flight_gen: int = 0


@dataclass
class _Publishers:
    prediction: Publisher
    status: Publisher


@dataclass
class _Stats:
    jitter_ms: _Window = field(default_factory=_Window)
    lateness_ms: _Window = field(default_factory=_Window)
    missed_ticks: int = 0
    published: int = 0
    recording_errors: int = 0


class Service:
    """The daemon's loop over one transport and a set of robots.

    Parameters
    ----------
    config
        The validated configuration.
    transport
        Zenoh, or :class:`~roger_daemon.transport.MemoryTransport` in unit tests.
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
        checkpoint_meta: Callable[[RobotRuntime], dict[str, Any]] | None = None,
    ) -> None:
        self.config = config
        self.transport = transport
        self.robots = dict(robots)
        self.notifier = notifier or Notifier(None)
        self.recorders = dict(recorders or {})
        self.clock: Clock = clock or _RealClock()
        self.inbox = Inbox(max(4 * config.queue_size, 1024))
        self.unserved: Counter[str] = Counter()
        self.stats = _Stats()
        self.resumed = dict(resumed or {})
        self._checkpoint_meta = checkpoint_meta
        self._sync_ckpt = sync_checkpoints
        self._writer: ThreadPoolExecutor | None = None
        self._ckpt = {r: _CheckpointState() for r in self.robots}
        self._pubs: dict[str, _Publishers] = {}
        self._period_ns = int(round(1e9 / config.rate_hz))
        self._status_period_ns = int(round(1e9 / config.status_hz))
        self._realtime = config.clock == "realtime"
        self._next_tick = 0
        self._last_fire: int | None = None
        self._learned_since_tick = False
        self._learn_est_ns = 0
        self._rr = 0
        self._next_status = 0
        self._started_ns = 0
        self._stop = False
        self._stopping = False
        self._answer: list[tuple[RobotRuntime, Perception, int]] = []
        self.final_checkpoints_ok = True
        self._reported: set[str] = set()
        self._recorder_failed: set[str] = set()
        self._health = {r: Health() for r in self.robots}
        # per robot: (controls applied, op of the last one, its stamp_ns) -- the confirmation
        self._acks: dict[str, tuple[int, str, int]] = {r: (0, "", 0) for r in self.robots}

    # --- life cycle ----------------------------------------------------------------------

    def start(self) -> None:
        """Declare publishers, subscribers and the liveliness token; then READY=1."""
        now = self.clock.monotonic_ns()
        self._started_ns = now
        for rt in self.robots.values():
            self._ckpt[rt.robot].generation = rt.generation
            self._ckpt[rt.robot].time_ns = now
            self._ckpt[rt.robot].updates = rt.updates
            self._pubs[rt.robot] = _Publishers(
                self.transport.publisher(keys.prediction(rt.robot), realtime=True),
                self.transport.publisher(keys.status(rt.robot), realtime=False),
            )
        # One subscriber (one callback thread) for everything: samples from one sender keep
        # their order (action(t) before perception(t+1)), which lockstep determinism needs.
        self.transport.subscribe(keys.everything(), self.inbox.put)
        self.transport.declare_token(keys.daemon_liveliness(self.config.id))
        if not self._sync_ckpt:
            self._writer = ThreadPoolExecutor(max_workers=1, thread_name_prefix="roger-ckpt")
        self._next_tick = now + self._period_ns
        self._next_status = now + self._status_period_ns
        for rt in self.robots.values():  # the baseline that health changes are judged from
            self._health[rt.robot].assess(self.status_of(rt, now).to_map(), now)
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
        self._stopping = True
        self.notifier.stopping("aborting after an error")
        if self._writer is not None:
            self._writer.shutdown(wait=True)
        for robot, rec in self.recorders.items():
            try:
                rec.close()
            except Exception as exc:
                self._recording_error(robot, "close", exc)
        self.transport.close()

    # --- one cycle -------------------------------------------------------------------------

    def step(self, max_wait_s: float = 0.05) -> None:
        """One cycle of the loop (see the module docstring)."""
        now = self.clock.monotonic_ns()
        if self._can_learn(now):
            wait = 0.0
        else:
            wait = max(0.0, min(max_wait_s, (self._next_deadline() - now) / 1e9))
        item = self.inbox.get(wait)
        # bounded, so that a backlog (lockstep runs ahead of learning) never starves status,
        # checkpoints, the watchdog or a stop request: the rest waits for the next cycle
        budget = min(self.inbox.capacity, MAX_DRAIN_PER_STEP)
        while item is not None and budget > 0:
            self._handle(item)
            budget -= 1
            item = self.inbox.get(0) if budget > 0 else None
        if self._answer:
            self._answer_lockstep()
        now = self.clock.monotonic_ns()
        if self._realtime and now >= self._next_tick:
            self._on_timer(now)
            now = self.clock.monotonic_ns()
        if self._can_learn(now):
            self._learn_once()
            now = self.clock.monotonic_ns()
        if now >= self._next_status:
            self._publish_status(now)
            self._next_status += self._status_period_ns
            if self._next_status <= now:
                self._next_status = now + self._status_period_ns
        self._periodic_checkpoints(now)
        self._collect_checkpoints()
        self._poll_recorders()
        self.notifier.watchdog(now)

    def _next_deadline(self) -> int:
        deadline = self._next_status
        if self._realtime and self._timer_active():
            deadline = min(deadline, self._next_tick)
        return deadline

    def _timer_active(self) -> bool:
        return any(rt.predicting and rt.newest is not None for rt in self.robots.values())

    def _can_learn(self, now: int) -> bool:
        if not any(rt.learning and rt.queue for rt in self.robots.values()):
            return False
        if not self._realtime or not self._timer_active() or not self._learned_since_tick:
            return True
        return now + self._learn_est_ns + _MS < self._next_tick

    def _learn_once(self) -> None:
        robots = list(self.robots.values())
        for i in range(len(robots)):
            rt = robots[(self._rr + i) % len(robots)]
            if rt.learning and rt.queue:
                self._rr = (self._rr + i + 1) % len(robots)
                ms = rt.learn_one()
                ns = int(ms * _MS)
                self._learn_est_ns = max(ns, int(self._learn_est_ns * 0.95))
                self._learned_since_tick = True
                return

    # --- intake ----------------------------------------------------------------------------

    def _handle(self, item: Incoming) -> None:
        parts = item.key.split("/")
        robot = parts[1] if len(parts) == 3 else ""
        rt = self.robots.get(robot)
        try:
            served_robot, kind = keys.parse(item.key)
        except ProtocolError as exc:
            if rt is not None or self.config.count_unserved:
                self._invalid(rt, exc.reason, exc.detail)
            return
        if rt is None:
            if kind in INPUT_KINDS and self.config.count_unserved:
                self._invalid(None, "unknown_robot",
                              f"message on {item.key}: robot {served_robot!r} is not served")
            return
        if kind not in INPUT_KINDS and not (kind in RECORD_ONLY_KINDS and robot in self.recorders):
            return  # e.g. predictions and status of other daemons
        if item.payload is None:
            self._invalid(rt, "oversized",
                          f"{kind}: payload of {item.size} bytes > {MAX_PAYLOAD_BYTES}")
            return
        try:
            msg = decode(kind, item.payload, dims=rt.dims, robot=robot)
        except ProtocolError as exc:
            if kind in INPUT_KINDS:
                self._invalid(rt, exc.reason, exc.detail)
            self._record(robot, item.key, item.payload, item.recv_wall_ns, item.recv_wall_ns, 0)
            return
        self._record(robot, item.key, item.payload, item.recv_wall_ns, msg.stamp_ns, msg.tick)
        dropped = rt.dropped
        if kind == "perception":
            assert isinstance(msg, Perception)
            rt.on_perception(msg, item.recv_ns)
            if not self._realtime and rt.predicting and not self._stopping:
                self._answer.append((rt, msg, item.recv_ns))
        elif kind == "action":
            assert isinstance(msg, Action)
            rt.on_action(msg)
        elif kind == "control":
            assert isinstance(msg, Control)
            self._control(rt, msg)
        if rt.dropped != dropped and robot in self.recorders:
            self._record_drop(rt, msg.tick, item.recv_wall_ns)

    def _record_drop(self, rt: RobotRuntime, tick: int, wall_ns: int) -> None:
        """Name the pair just dropped (queue full) in the log, so that replay stays exact."""
        from roger_daemon.recording.events import dropped_topic, encode_dropped

        payload = encode_dropped(rt.robot, tick, stamp_ns=wall_ns, queue_size=rt.queue_size,
                                 dropped=rt.dropped)
        self._record(rt.robot, dropped_topic(rt.robot), payload, wall_ns, wall_ns, tick)

    def _answer_lockstep(self) -> None:
        """Lockstep: learn every complete pair first, then answer the perceptions just drained.

        So prediction(t+1) includes pair t whenever action(t) arrived before perception(t+1),
        which is the causal order of a lock-stepped simulator (deterministic runs).
        """
        answer, self._answer = self._answer, []
        for rt in {id(a[0]): a[0] for a in answer}.values():
            while rt.learning and rt.queue:
                rt.learn_one()
        for rt, msg, recv_ns in answer:
            self._publish_prediction(rt, msg, recv_ns)

    def _invalid(self, rt: RobotRuntime | None, reason: str, detail: str) -> None:
        if rt is not None:
            rt.count_invalid(reason, detail)
            return
        self.unserved[reason] += 1
        if reason not in self._reported:
            self._reported.add(reason)
            log.warning("rejected message (%s); further ones are only counted", detail)

    def _control(self, rt: RobotRuntime, msg: Control) -> None:
        if msg.op == "mode":
            if msg.mode != rt.mode:
                log.info("%s: mode %s -> %s", rt.robot, rt.mode, msg.mode)
            rt.mode = msg.mode
        elif msg.op == "reset":
            log.info("%s: reset requested: forgetting %d learned pairs", rt.robot, rt.updates)
            rt.reset()
        elif msg.op == "checkpoint":
            log.info("%s: checkpoint requested", rt.robot)
            self._checkpoint(rt, "requested")
        n = self._acks[rt.robot][0] + 1
        self._acks[rt.robot] = (n, msg.op, msg.stamp_ns)
        # confirm at once: a status carrying this control's stamp (protocols/README.md, control)
        now = self.clock.monotonic_ns()
        st = self.status_of(rt, now)
        self._publish(rt, self._pubs[rt.robot].status, keys.status(rt.robot), st)

    # --- output ----------------------------------------------------------------------------

    def _publish(self, rt: RobotRuntime, pub: Publisher, key: str, msg: Message) -> None:
        payload = encode(msg)
        pub.put(payload)
        self._record(rt.robot, key, payload, self.clock.time_ns(), msg.stamp_ns, msg.tick)

    def _publish_prediction(self, rt: RobotRuntime, perc: Perception, recv_ns: int) -> None:
        try:
            pred = rt.predict(perc, recv_ns, self.clock.monotonic_ns)
        except Exception as exc:  # prediction only reads the model: skip it, keep serving
            rt.predict_errors += 1
            if rt.predict_errors == 1:
                log.exception("%s: prediction for tick %d failed (%s); further failures are "
                              "only counted", rt.robot, perc.tick, exc)
            return
        self._publish(rt, self._pubs[rt.robot].prediction, keys.prediction(rt.robot), pred)
        self.stats.published += 1

    def _on_timer(self, now: int) -> None:
        continuing = self._last_fire is not None  # the previous tick published too
        published = False
        for rt in self.robots.values():
            if rt.predicting and rt.newest is not None and not self._stopping:
                perc, recv_ns = rt.newest
                self._publish_prediction(rt, perc, recv_ns)
                published = True
        self._learned_since_tick = False
        if not published:
            self._last_fire = None
            self._next_tick = max(self._next_tick + self._period_ns, now)
            return
        if not continuing:
            # First tick after an idle stretch: start a fresh schedule from now.
            self._last_fire = now
            self._next_tick = now + self._period_ns
            return
        assert self._last_fire is not None
        self.stats.lateness_ms.add((now - self._next_tick) / _MS)
        self.stats.jitter_ms.add(abs((now - self._last_fire) - self._period_ns) / _MS)
        self._last_fire = now
        self._next_tick += self._period_ns
        if self._next_tick <= now:  # overran whole periods: skip them, count them
            missed = (now - self._next_tick) // self._period_ns + 1
            self.stats.missed_ticks += int(missed)
            self._next_tick += int(missed) * self._period_ns

    # --- status ----------------------------------------------------------------------------

    def status_of(self, rt: RobotRuntime, now: int) -> Status:
        ck = self._ckpt[rt.robot]
        invalid = Counter(rt.invalid)
        invalid.update(self.unserved)
        info: dict[str, Any] = {
            "clock": self.config.clock,
            "rate_hz": self.config.rate_hz,
            "period_jitter_ms_p50": round(self.stats.jitter_ms.pct(50), 4),
            "period_jitter_ms_p99": round(self.stats.jitter_ms.pct(99), 4),
            "tick_lateness_ms_p99": round(self.stats.lateness_ms.pct(99), 4),
            "missed_ticks": self.stats.missed_ticks,
            "learn_ms_p50": round(rt.learn_ms.pct(50), 4),
            "learn_ms_p99": round(rt.learn_ms.pct(99), 4),
            "predict_ms_p50": round(rt.predict_ms.pct(50), 4),
            "unpaired_actions": rt.unpaired,
            "learn_errors": rt.learn_errors,
            "predict_errors": rt.predict_errors,
            "inbox_overflow": self.inbox.overflow,
            "inbox_depth": len(self.inbox),
            "labels": len(rt.vocab),
            "checkpoint": ck.path,
            "checkpoint_updates": ck.updates,
            "checkpoint_digest": ck.digest,
            "checkpoints_written": ck.written,
            "checkpoint_errors": ck.errors,
            "resumed_from": self.resumed.get(rt.robot, ""),
            "recovered_pairs": rt.recovered_pairs,
            "last_learned_tick": -1 if rt.last_learned_tick is None else rt.last_learned_tick,
            "recording": rt.robot in self.recorders,
            "recording_errors": self.stats.recording_errors,
            "controls": self._acks[rt.robot][0],
            "control_op": self._acks[rt.robot][1],
            "control_stamp_ns": self._acks[rt.robot][2],
            "level": self._health[rt.robot].last[0],
            "level_reasons": self._health[rt.robot].last[1],
        }
        return Status(
            rt.robot, rt.last_tick, rt.last_t, daemon=self.config.id, mode=rt.mode,
            ticks=rt.ticks, updates=rt.updates, updates_per_s=rt.updates_per_s(now),
            experts=int(rt.model.n_experts), queue_depth=len(rt.queue), dropped=rt.dropped,
            invalid=dict(invalid), latency_ms_p50=rt.latency.pct(50),
            latency_ms_p99=rt.latency.pct(99), uptime_s=(now - self._started_ns) / 1e9,
            info=info,
        )

    def _publish_status(self, now: int) -> None:
        lines = []
        for rt in self.robots.values():
            st = self.status_of(rt, now)
            before = self._health[rt.robot].last[0]
            level, reasons = self._health[rt.robot].assess(st.to_map(), now)
            if level != before:  # into the journal too: journalctl -p warning shows it
                log.log(LOG_LEVEL_OF[level], "%s: status %s%s", rt.robot, level,
                        f" ({reasons})" if reasons else "")
            st = replace(st, info={**st.info, "level": level, "level_reasons": reasons})
            self._publish(rt, self._pubs[rt.robot].status, keys.status(rt.robot), st)
            lines.append(
                f"{rt.robot}: {st.mode}, {st.updates} updates ({st.updates_per_s:.1f}/s), "
                f"{st.experts} experts, queue {st.queue_depth}, dropped {st.dropped}, "
                f"p99 {st.latency_ms_p99:.1f} ms, {level}"
            )
        self.notifier.status("; ".join(lines))

    # --- checkpoints -----------------------------------------------------------------------

    def _periodic_checkpoints(self, now: int) -> None:
        c = self.config.checkpoint
        for rt in self.robots.values():
            st = self._ckpt[rt.robot]
            if st.in_flight is not None or rt.generation == st.generation:
                continue
            by_updates = c.every_updates > 0 and rt.generation - st.generation >= c.every_updates
            by_time = c.every_s > 0 and now - st.time_ns >= c.every_s * 1e9
            if by_updates or by_time:
                self._checkpoint(rt, "periodic")

    def _snapshot(self, rt: RobotRuntime, reason: str) -> tuple[dict[str, Any], ...]:
        rec = self.recorders.get(rt.robot)
        return checkpoint_snapshot(
            rt, reason, daemon_id=self.config.id, created_unix_ns=self.clock.time_ns(),
            session_id=str(getattr(rec, "session_id", "") or ""),
            session_segment=rt.session_resets,
            extra=self._checkpoint_meta(rt) if self._checkpoint_meta is not None else None,
        )

    def _checkpoint(self, rt: RobotRuntime, reason: str, *, sync: bool = False) -> None:
        st = self._ckpt[rt.robot]
        model, daemon, meta = self._snapshot(rt, reason)
        c = self.config.checkpoint
        st.time_ns = self.clock.monotonic_ns()
        gen = rt.generation
        if sync or self._writer is None:
            if st.in_flight is not None:
                self._collect_checkpoints(wait=True)
            try:
                path, full = write_checkpoint(c.dir, rt.robot, model, daemon, meta, keep=c.keep)
            except Exception as exc:
                self._checkpoint_failed(rt.robot, exc)
                return
            self._checkpoint_done(rt.robot, gen, path, full)
            return
        if st.in_flight is not None:
            return
        st.in_flight = self._writer.submit(
            write_checkpoint, c.dir, rt.robot, model, daemon, meta, keep=c.keep
        )
        st.in_flight_gen = gen

    def _checkpoint_done(self, robot: str, gen: int, path: Path, meta: dict[str, Any]) -> None:
        st = self._ckpt[robot]
        st.generation, st.path, st.updates = gen, str(path), int(meta["updates"])
        st.digest = str(meta["model_digest"])
        st.written += 1
        log.info("%s: checkpoint %s written (%s, %d updates, model %s)", robot, path,
                 meta.get("reason", ""), st.updates, st.digest[:12])

    def _checkpoint_failed(self, robot: str, exc: BaseException) -> None:
        self._ckpt[robot].errors += 1
        if self._stopping:
            self.final_checkpoints_ok = False
        log.error("%s: checkpoint failed: %s", robot, exc)

    def _collect_checkpoints(self, wait: bool = False) -> None:
        for robot, st in self._ckpt.items():
            fut = st.in_flight
            if fut is None or not (wait or fut.done()):
                continue
            st.in_flight = None
            try:
                path, meta = fut.result()
            except Exception as exc:
                self._checkpoint_failed(robot, exc)
                continue
            self._checkpoint_done(robot, st.in_flight_gen, path, meta)

    # --- recording -------------------------------------------------------------------------

    def _record(self, robot: str, key: str, payload: bytes, log_ns: int, pub_ns: int,
                seq: int) -> None:
        rec = self.recorders.get(robot)
        if rec is None:
            return
        try:
            rec.write(key, payload, log_time_ns=log_ns, publish_time_ns=pub_ns, sequence=seq)
        except Exception as exc:
            self._recording_error(robot, "write", exc)

    def _poll_recorders(self) -> None:
        if not self.recorders:
            return
        now = self.clock.monotonic_ns()
        for robot, rec in self.recorders.items():
            try:
                rec.poll(now)
            except Exception as exc:
                self._recording_error(robot, "poll", exc)

    def _recording_error(self, robot: str, what: str, exc: BaseException) -> None:
        self.stats.recording_errors += 1
        if robot not in self._recorder_failed:
            self._recorder_failed.add(robot)
            log.error("%s: recorder %s failed: %s (further errors only counted)", robot, what,
                      exc)

    # --- shutdown --------------------------------------------------------------------------

    def shutdown(self) -> None:
        """Stop intake, drain, learn what fits, checkpoint, close recorders and transport."""
        if self._stopping:
            return
        self._stopping = True
        t0 = time.monotonic()
        self.notifier.stopping("shutting down: draining and checkpointing")
        log.info("shutting down: stopping intake")
        try:
            self.transport.stop_intake()
            item = self.inbox.get(0)
            while item is not None:
                self._handle(item)
                item = self.inbox.get(0)
            budget = self.config.checkpoint.shutdown_learn_s
            while time.monotonic() - t0 < budget and any(
                rt.learning and rt.queue for rt in self.robots.values()
            ):
                self._learn_once()
            self._collect_checkpoints(wait=True)
            if self.config.checkpoint.on_shutdown:
                for rt in self.robots.values():
                    if rt.generation != self._ckpt[rt.robot].generation or rt.queue:
                        self._checkpoint(rt, "shutdown", sync=True)
                    else:
                        log.info("%s: checkpoint %s is up to date", rt.robot,
                                 self._ckpt[rt.robot].path or "(none: nothing learned)")
            queued = sum(len(rt.queue) for rt in self.robots.values())
            if queued:
                log.info("%d queued pairs not learned before shutdown%s", queued,
                         "; saved in the checkpoint" if self.config.checkpoint.on_shutdown
                         else "; LOST (checkpoint.on_shutdown = false)")
        finally:
            if self._writer is not None:
                self._writer.shutdown(wait=True)
            for robot, rec in self.recorders.items():
                try:
                    rec.close()
                except Exception as exc:
                    self._recording_error(robot, "close", exc)
            self.transport.close()
            log.info("shut down in %.2f s", time.monotonic() - t0)
