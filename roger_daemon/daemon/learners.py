"""The daemon's side of the learner workers: worker processes own the robots' models.

With ``[daemon] workers = "process"`` (what ``"auto"`` picks for several robots) the loop
keeps Zenoh, pairing, the training queues, the write-ahead log, recording, status and
publishing; each robot's model lives in a worker process (:mod:`roger_daemon.daemon.worker`;
by default one process per core, each serving several robots' models, ``[daemon]
worker_processes``), started with ``subprocess`` (a fresh interpreter: nothing forked after
Zenoh opened, nothing pickled) and driven over its stdin/stdout with msgpack frames (the
processes and pipes: :mod:`roger_daemon.daemon.worker_procs`; this module schedules requests
and books replies). Robots learn in parallel on every core.

Ordering is what keeps the daemon's guarantees: a worker answers its requests one by one, in
order, and the loop reads each robot's replies in that order (its wait includes the workers'
pipes: :meth:`WorkerProcesses.read_replies`). So

- a learn reply is bookkept (label code, write-ahead log record, ``updates``) exactly as an
  in-process ``learn_one`` would be, and in the same order;
- a prediction reflects every pair sent before it; when it arrives, every earlier learn reply
  has been bookkept, so the loop commits the log and then publishes (acknowledged means
  durable); lockstep sends the queued pairs, then the prediction request, so prediction(t)
  includes what it includes in-process (replay stays exact);
- a snapshot (checkpoint) is consistent with the loop's bookkeeping when it arrives; pairs
  sent after the snapshot request go to the front of the checkpoint's queue;
- ``reset`` first sends the robot's queued pairs and drains its requests (replies
  bookkept), then replaces its model.

At most one learn request is in flight per worker process (``process_depth``), so a
prediction waits for at most one learning step of another robot its process serves (besides
its own robot's pairs, which it must include; docs/fleet.md, *One learning step ahead of an
answer*). In realtime the prediction is prepared when
the perception arrives (:meth:`ProcessLearners.prepare`, one in flight per robot, the newest
perception next) and the timer's tick publishes the newest prepared one of every robot at once
(:meth:`ProcessLearners.prepared`): no tick waits for eight workers to be scheduled
(docs/fleet.md, *Prepared predictions*). A tick with nothing prepared yet for a robot that has
a perception is counted as ``info.worker_busy_ticks``. A worker that dies or answers ``fatal``
raises :class:`WorkerError` in the loop, which aborts the daemon (exit 1; the write-ahead log
holds every acknowledged pair for the restart); a wait for a worker has a deadline and never
hangs.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np

from roger_daemon.daemon.learner_host import Answer, Replies, log_seq
from roger_daemon.daemon.robot import Pair, RobotRuntime
from roger_daemon.daemon.tick_windows import TickWindows
from roger_daemon.daemon.worker import pack_arrays, unpack_arrays
from roger_daemon.daemon.worker_procs import (
    RemoteModel,
    WorkerError,
    WorkerProcess,
    WorkerProcesses,
    WorkerSlot,
)

__all__ = ["ProcessLearners", "RemoteModel", "WorkerError"]

log = logging.getLogger(__name__)

#: the deadline of the first worker's start: on a cold numba cache it compiles every kernel
#: (~40 s on an idle 2-core machine, several times that on a busy one)
COMPILE_TIMEOUT_S = 900.0


def _vec(a: np.ndarray) -> bytes:
    return np.ascontiguousarray(a, dtype="<f8").tobytes()


class ProcessLearners(WorkerProcesses):
    """The robots' models in worker processes (a :class:`~.learner_host.Learners`); see the
    module docstring.

    Parameters
    ----------
    robots
        The runtimes, models loaded (and recovered) in this process; each model is handed to
        its worker and replaced by a :class:`RemoteModel`.
    configs
        Robot id -> :class:`~roger_daemon.config.RobotConfig` (model kind, seed, params).
    processes
        Worker processes (``[daemon] worker_processes``; 0: one per usable core, at most one
        per robot); each serves the models of the robots assigned to it.
    timeout_s
        Deadline of every blocking wait for a worker (start, snapshot, drain).
    nice
        How much lower the workers' CPU priority is than the loop's (``[daemon]
        worker_nice``): the loop and Zenoh's threads publish before learning runs.
    """

    depth = 1  # learn requests in flight per robot
    process_depth = 1  # ... and per worker process, whichever robots they are for
    prepares = True  # realtime: predictions prepared as perceptions arrive (prepare)
    in_process = False  # the models live in the workers

    def __init__(self, robots: Mapping[str, RobotRuntime], configs: Mapping[str, Any], *,
                 processes: int = 0, timeout_s: float = 120.0, nice: int = 0) -> None:
        self._results: Replies | None = None
        self.windows = TickWindows()  # the realtime tick's windows (pump, new_tick)
        super().__init__(robots, processes=processes, timeout_s=timeout_s, nice=nice)
        def loaded() -> bool:
            return all(not s.pending for s in self.slots.values())

        try:
            for k, (robot, rt) in enumerate(robots.items()):
                self._load(robot, rt, configs[robot])
                if k == 0:  # its worker warms up alone first: on a cold numba cache it
                    # compiles the kernels and writes the cache the other workers then load,
                    # instead of every worker compiling them (docs/fleet.md, *The design*)
                    self._wait(loaded, "start, warming up the learner's kernels",
                               timeout_s=max(timeout_s, COMPILE_TIMEOUT_S))
            self._wait(loaded, "start")
        except BaseException:
            self.close(kill=True)
            raise
        for robot, s in self.slots.items():
            log.info("%s: learner worker pid %d owns the model (%d updates)", robot,
                     s.proc.pid, s.rt.updates)

    def _load(self, robot: str, rt: RobotRuntime, cfg: Any) -> None:
        self.send(robot, {
            "op": "load", "robot": robot, "x_dim": rt.dims.x, "y_dim": rt.dims.y,
            "model": cfg.model, "seed": cfg.seed, "params": cfg.params.to_mapping(),
            "state": pack_arrays(rt.model.state_dict()),
            "codes": pack_arrays({"codes": rt.codes}),
        }, None)
        model = RemoteModel(self, robot, rt.updates, int(rt.model.n_experts))
        self.slots[robot].model = model
        rt.model = model
        rt.make_model = model.fresh

    def attach(self, replies: Replies) -> None:
        """Route replies to ``replies`` (the loop waits for them: :meth:`fds`)."""
        self._results = replies
        self.windows.period_ns = int(replies.period_ns)

    def _sink(self) -> Replies:
        if self._results is None:
            raise WorkerError("a worker replied before the service attached")
        return self._results

    def has_work(self, now: int, deadline_ns: int | None) -> bool:
        """Whether replies are waiting to be handled (:meth:`pump`)."""
        return self.has_replies()

    def learn(self, now: int, deadline_ns: int | None) -> None:
        """Nothing on the loop's thread: the workers learn (:meth:`feed`)."""

    def learn_more(self) -> None:
        """Shutdown: handle replies and feed the workers; then the next reply (waited for up
        to 50 ms), and again."""
        self.pump()
        if not self._replies:
            self.read_replies(0.05)
        if (item := self.next_reply()) is not None:
            self._dispatch(*item)
            self.pump()

    def wake_ns(self) -> int | None:
        """When the delivery window after a tick closes (:mod:`.tick_windows`)."""
        return self.windows.wake_ns()

    def delivering(self) -> bool:
        """Whether the tick's predictions are still being delivered (:mod:`.tick_windows`)."""
        return self.windows.delivering()

    def publish_tick(self, due: Sequence[RobotRuntime]) -> bool:
        """Publish the newest prepared prediction of each of ``due`` at once."""
        batch = self.prepared(due)
        if batch:
            self._sink().publish(batch)
        return bool(batch)

    # --- replies ---------------------------------------------------------------------------

    def pump(self, deadline_ns: int | None = None) -> None:
        """Handle every reply that arrived, then keep each worker fed with learning
        (:meth:`feed`). Predictions of the batch are published together
        (``Replies.publish``: one parallel write-ahead log commit for all).

        ``deadline_ns`` (realtime: the next timer tick) starts the quiet window before it: no
        worker starts a step then that is not expected back before the tick, so the cores
        are free when the loop wakes to publish (``None``: no timer)."""
        self.windows.deadline_ns = deadline_ns
        batch: list[Answer] = []
        self.read_replies()
        while (item := self.next_reply()) is not None:
            self._dispatch(*item, batch=batch)
        if batch:
            self._sink().publish(batch)
        self.feed()

    def _dispatch(self, robot: str, frame: dict[str, Any] | None,
                  batch: list[Answer] | None = None) -> None:
        if frame is None:
            raise WorkerError(self._died(robot, "it exited"))
        if "fatal" in frame:
            raise WorkerError(self._died(robot, str(frame["fatal"])))
        s = self.slots[robot]
        op, ctx = s.pending.popleft()
        if op == "learn":
            s.learns -= 1
            pair, sent_ns = ctx
            s.learn_est_ns = max(time.monotonic_ns() - sent_ns, int(s.learn_est_ns * 0.95))
            self._learned(s, pair, frame)
        elif op == "predict":
            s.predicts -= 1
            perc, recv_ns, prepared, sent_ns = ctx
            s.predict_est_ns = max(time.monotonic_ns() - sent_ns,
                                   int(s.predict_est_ns * 0.95))
            # every learn reply before it is bookkept: the log up to here is what it counts
            item = (s.rt, frame, perc, recv_ns, log_seq(s.rt))
            if prepared:
                if frame.get("ok"):
                    s.ready = item[1:]
                    s.ready_updates = s.model.n_learned if s.model is not None else 0
                else:  # counted and logged there; the tick keeps the last good one
                    self._sink().publish([item])
                self._prepare_waiting(s)
            elif batch is not None:
                batch.append(item)
            elif self._results is not None:
                self._results.publish([item])
        elif op == "snapshot":
            s.snapshots -= 1
            ahead = [c[0] for o, c in s.pending if o == "learn"]
            reason, sync = ctx
            self._sink().write_snapshot(s.rt, reason,
                                        unpack_arrays(frame["state"], copy=False),
                                        ahead=ahead, sync=sync)
        elif op in ("load", "fresh") and s.model is not None:
            s.model.n_learned, s.model.n_experts = int(frame["n"]), int(frame["experts"])

    def _learned(self, s: WorkerSlot, pair: Pair, frame: dict[str, Any]) -> None:
        if not frame.get("ok"):
            s.rt.learn_errors += 1
            log.error("%s: learning the pair of tick %d failed; pair skipped (see the "
                      "worker's log line)", s.rt.robot, pair.tick)
            return
        assert s.model is not None
        s.model.n_learned, s.model.n_experts = int(frame["n"]), int(frame["experts"])
        s.rt.learned(pair, float(frame["ms"]))

    # --- requests --------------------------------------------------------------------------

    @staticmethod
    def _with_vocab(s: WorkerSlot, req: dict[str, Any]) -> dict[str, Any]:
        """``req`` with the label vocabulary when it grew since the worker was last sent it
        (it only grows; a reset sends it again): the worker labels experts with it, while
        counting ahead and for a prediction."""
        if len(s.rt.vocab) != s.vocab_sent:
            req["vocab"] = list(s.rt.vocab)
            s.vocab_sent = len(s.rt.vocab)
        return req

    def _send_learn(self, s: WorkerSlot) -> None:
        pair = s.rt.queue.popleft()
        req = {"op": "learn", "x": _vec(pair.x), "y": _vec(pair.y), "code": pair.label,
               "tick": pair.tick}
        self.send(s.rt.robot, self._with_vocab(s, req), (pair, time.monotonic_ns()))
        s.learns += 1
        s.since_tick = True

    def feed(self) -> None:
        """Keep one learn request in flight per worker process (``process_depth``), its
        robots taking turns; in the quiet window before a tick only a robot that has not
        learned since the last tick starts one (so learning always progresses). Without a
        timer (lockstep) no learning starts while a prediction is being answered: the answers
        go first on the two cores, and a pair still queued when its robot's next perception
        comes is sent before that perception's request (:meth:`learn_all`), as before
        (docs/fleet.md, *Status after the answers*). So a prediction request waits behind at
        most one other robot's learning step in its worker (*One learning step ahead of an
        answer*). In the delivery window after a realtime tick nothing is sent; after it,
        the perceptions held back go first (:mod:`.tick_windows`)."""
        if (self.windows.deadline_ns is None and self.answering()) or \
                self.windows.delivering():
            return
        for s in self.slots.values():  # perceptions a window held back
            self._prepare_waiting(s)
        for wp in self.processes:
            self._feed_process(wp)

    def _feed_process(self, wp: WorkerProcess) -> None:
        in_flight = self.learns_in(wp)
        n = len(wp.robots)
        for k in range(n):
            if in_flight >= self.process_depth:
                return
            i = (wp.next_learn + k) % n
            s = self.slots[wp.robots[i]]
            if s.rt.learning and s.rt.queue and s.learns < self.depth and \
                    not (s.since_tick and self.windows.quiet(s.learn_est_ns)):
                self._send_learn(s)
                in_flight += 1
                wp.next_learn = (i + 1) % n

    def learns_in(self, wp: WorkerProcess) -> int:
        """Learn requests in flight in worker process ``wp``, of all its robots."""
        return sum(self.slots[r].learns for r in wp.robots)

    def new_tick(self, deadline_ns: int, *, published: bool = True) -> None:
        """The realtime timer fired (the next one is at ``deadline_ns``): if it ``published``,
        the delivery window opens, and :meth:`feed` sends nothing until it closes; then the
        perceptions held back are sent, and every robot may learn once more.

        A robot whose newest perception is more than a period old (it stopped or sends
        slower than the clock) has it predicted again once its model learned more, as the
        tick did when it computed the predictions itself."""
        now = time.monotonic_ns()
        self.windows.ticked(now, deadline_ns, published=published)
        for s in self.slots.values():
            s.since_tick = False
            newest = s.rt.newest
            if s.waiting is None and s.ready is not None and newest is not None and \
                    s.ready[1] is newest[0] and now - newest[1] > self.windows.period_ns and \
                    s.model is not None and s.model.n_learned > s.ready_updates:
                s.waiting = newest
            self._prepare_waiting(s)

    def learn_all(self, rt: RobotRuntime) -> None:
        """Send every queued pair of ``rt`` (lockstep: before answering a perception)."""
        s = self.slots[rt.robot]
        while rt.learning and rt.queue:
            self._send_learn(s)

    def predict(self, rt: RobotRuntime, perc: Any, recv_ns: int) -> None:
        """Ask for a prediction (lockstep); the reply goes to ``Replies.publish``."""
        self._send_predict(self.slots[rt.robot], perc, recv_ns, prepared=False)

    def prepare(self, rt: RobotRuntime, perc: Any, recv_ns: int) -> None:
        """Realtime: prepare the prediction for ``perc``, just received, for the next tick.

        One request is in flight per robot; a perception that arrives meanwhile waits, and
        only the newest waiting one is sent when the reply comes."""
        s = self.slots[rt.robot]
        s.waiting = (perc, recv_ns)
        self._prepare_waiting(s)

    def _prepare_waiting(self, s: WorkerSlot) -> None:
        """Send the waiting perception unless one is in flight, the tick is too close (it
        would not be ready for it: it goes after the tick, :meth:`new_tick`) or the tick's
        predictions are being delivered (it goes when :meth:`feed` runs after that)."""
        if s.waiting is not None and not s.predicts and not self.windows.delivering() and \
                not self.windows.quiet(s.predict_est_ns):
            self._send_predict(s, *s.waiting, prepared=True)
            s.waiting = None

    def prepared(self, robots: Iterable[RobotRuntime]) -> list[Answer]:
        """The tick: the newest prepared prediction of each of ``robots`` (for
        ``Replies.publish``); a robot with none yet counts a busy tick."""
        out = []
        for rt in robots:
            s = self.slots[rt.robot]
            if s.ready is None:
                s.busy_ticks += 1
            else:
                out.append((rt, *s.ready))
        return out

    def _send_predict(self, s: WorkerSlot, perc: Any, recv_ns: int, *, prepared: bool) -> None:
        req = {"op": "predict", "x": _vec(perc.x), "tick": perc.tick, "t": perc.t}
        self.send(s.rt.robot, self._with_vocab(s, req),
                  (perc, recv_ns, prepared, time.monotonic_ns()))
        s.predicts += 1

    def snapshot(self, rt: RobotRuntime, reason: str, *, sync: bool) -> None:
        """Ask for the model's state; the reply goes to ``Replies.write_snapshot``."""
        s = self.slots[rt.robot]
        if s.snapshots and not sync:
            return
        self.send(rt.robot, {"op": "snapshot"}, (reason, sync))
        s.snapshots += 1
        if sync:
            self.drain(rt)

    def drain(self, rt: RobotRuntime | None = None) -> None:
        """Wait until every request sent (to ``rt``'s worker, or all) is answered."""
        slots = list(self.slots.values()) if rt is None else [self.slots[rt.robot]]
        self._wait(lambda: not any(s.pending for s in slots), "drain")

    def answering(self) -> bool:
        """True while a prediction request is in flight."""
        return any(s.predicts for s in self.slots.values())

    def learning(self) -> bool:
        """True while learn requests are in flight."""
        return any(s.learns for s in self.slots.values())

    def info(self, rt: RobotRuntime) -> dict[str, Any]:
        """The worker's part of the robot's status ``info``."""
        s = self.slots[rt.robot]
        return {"workers": "process", "worker_pid": s.proc.pid, "worker_nice": self.nice,
                "worker_processes": len(self.processes), "worker_busy_ticks": s.busy_ticks}
