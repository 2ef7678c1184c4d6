"""Learner worker processes and their pipes: start, send, read, fail, stop.

The process side of :class:`~roger_daemon.daemon.learners.ProcessLearners` (which schedules
the requests and books the replies): ``python -m roger_daemon.daemon.worker`` processes,
started with ``subprocess`` (a fresh interpreter, nothing forked after Zenoh opened),
``--nice`` lower than the loop; by default one per usable core, each serving the models of
every robot assigned to it, robot ``i`` to process ``i mod n`` (:func:`pool_size`;
docs/fleet.md, *A pool of workers*). A process answers its requests in order, so its replies
are matched to their robots by the order they were sent (``WorkerProcess.owners``). The loop
reads the replies itself: the workers' output pipes are non-blocking and the loop waits for
them and for its inbox in one ``select`` (:meth:`WorkerProcesses.fds`,
:class:`~roger_daemon.transport.Inbox`), then reads whatever arrived
(:meth:`WorkerProcesses.read_replies`), in order per worker: no reader thread takes the GIL
between a reply and the loop (docs/fleet.md, *One wait*). A request's context waits in its
robot's ``WorkerSlot.pending`` until its reply is dispatched; every blocking wait has a
deadline (docs/fleet.md, *Failure*).
"""

from __future__ import annotations

import logging
import os
import select
import subprocess
import sys
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from roger_daemon.daemon.robot import RobotRuntime
from roger_daemon.daemon.worker import FrameReader, write_frame
from roger_daemon.machine import usable_cores

__all__ = ["RemoteModel", "WorkerError", "WorkerProcess", "WorkerProcesses", "WorkerSlot",
           "pool_size", "threads_per_worker"]

log = logging.getLogger(__name__)


class WorkerError(RuntimeError):
    """A learner worker died, failed or did not answer in time."""


@dataclass
class WorkerProcess:
    """One worker process: its pipes and the robot of each request in flight, in order."""

    proc: subprocess.Popen[bytes]
    reader: FrameReader  # its replies, read as they arrive (non-blocking)
    robots: list[str] = field(default_factory=list)  # the robots it serves
    owners: deque[str] = field(default_factory=deque)  # whose request each next reply answers
    next_learn: int = 0  # where its robots' turn to learn starts (round robin)


@dataclass
class WorkerSlot:
    """One robot's place in its worker process: the requests in flight (op and context, in
    order) and the scheduler's state for it."""

    rt: RobotRuntime
    process: WorkerProcess
    model: RemoteModel | None = None
    pending: deque[tuple[str, Any]] = field(default_factory=deque)
    learns: int = 0
    predicts: int = 0
    snapshots: int = 0
    busy_ticks: int = 0
    learn_est_ns: int = 0  # send -> reply of a learn request, decaying maximum
    predict_est_ns: int = 0  # the same for a prediction
    since_tick: bool = False  # a learn was sent since the last timer tick
    # realtime: the newest prepared prediction (reply, perception, receipt ns, log seq it
    # needs durable) and the perception waiting for the one in flight
    ready: tuple[dict[str, Any], Any, int, int] | None = None
    ready_updates: int = 0  # the model updates the ready one counts
    vocab_sent: int = -1  # the label vocabulary's length the worker was sent last
    waiting: tuple[Any, int] | None = None

    @property
    def proc(self) -> subprocess.Popen[bytes]:
        """The worker process that owns this robot's model."""
        return self.process.proc


def threads_per_worker(processes: int) -> int:
    """Learner threads of each of ``processes`` worker processes: this process's usable
    cores shared out, at least one (docs/fleet.md)."""
    return max(1, usable_cores() // max(1, processes))


def pool_size(robots: int, processes: int = 0) -> int:
    """How many worker processes serve ``robots`` robots: ``processes`` (``[daemon]
    worker_processes``), or with 0 one per usable core; never more than one per robot."""
    want = processes if processes > 0 else usable_cores()
    return max(1, min(robots, want))


class RemoteModel:
    """``RobotRuntime.model`` when a worker owns the model: the counts the loop reports
    (:class:`~roger_daemon.daemon.learners.ProcessLearners` installs it).

    ``reset`` replaces the model through :meth:`fresh` (``RobotRuntime.make_model``).
    """

    def __init__(self, owner: WorkerProcesses, robot: str, n_learned: int,
                 n_experts: int) -> None:
        self._owner, self._robot = owner, robot
        self.n_learned = n_learned
        self.n_experts = n_experts

    def fresh(self) -> RemoteModel:
        """Replace the worker's model by a fresh one (a reset); returns ``self``."""
        self._owner.send(self._robot, {"op": "fresh"}, None)
        slot = self._owner.slots[self._robot]
        slot.ready = slot.waiting = None  # the old model's predictions are not published
        slot.vocab_sent = -1  # a reset starts the label vocabulary again
        self.n_learned, self.n_experts = 0, 0
        return self

    def state_dict(self) -> dict[str, np.ndarray]:
        """Not available: the model's state lives in the worker process."""
        raise WorkerError("the model lives in a worker process: use ProcessLearners.snapshot")



class WorkerProcesses:
    """The worker processes of the robots and their pipes.

    Parameters
    ----------
    robots
        The runtimes to serve (robot id -> runtime).
    processes
        How many processes serve them (``[daemon] worker_processes``; 0: one per usable
        core, :func:`pool_size`); robot ``i`` goes to process ``i mod n``.
    timeout_s
        Deadline of every blocking wait for a worker (start, snapshot, drain).
    nice
        How much lower the workers' CPU priority is than the loop's (``[daemon]
        worker_nice``): the loop and Zenoh's threads publish before learning runs.

    Each worker's learner runs its batched kernels on :func:`threads_per_worker` threads:
    the processes share the cores, so with as many processes as cores or more each learns
    on one.
    """

    def __init__(self, robots: Mapping[str, RobotRuntime], *, processes: int = 0,
                 timeout_s: float = 120.0, nice: int = 0) -> None:
        self.timeout_s = timeout_s
        self.nice = nice
        n = pool_size(len(robots), processes)
        threads = threads_per_worker(n)
        self._replies: deque[tuple[str, dict[str, Any] | None]] = deque()
        self.slots: dict[str, WorkerSlot] = {}
        self.processes: list[WorkerProcess] = []
        self._by_fd: dict[int, WorkerProcess] = {}
        try:
            for _ in range(n):  # start them all first: they import in parallel
                proc = subprocess.Popen([sys.executable, "-m", "roger_daemon.daemon.worker",
                                         "--nice", str(nice), "--threads", str(threads)],
                                        stdin=subprocess.PIPE, stdout=subprocess.PIPE)
                assert proc.stdout is not None
                raw = getattr(proc.stdout, "raw", proc.stdout)
                os.set_blocking(raw.fileno(), False)
                wp = WorkerProcess(proc, FrameReader(raw))
                self.processes.append(wp)
                self._by_fd[raw.fileno()] = wp
            for i, (robot, rt) in enumerate(robots.items()):
                wp = self.processes[i % n]
                wp.robots.append(robot)
                self.slots[robot] = WorkerSlot(rt, wp)
        except BaseException:
            self.close(kill=True)
            raise

    def _dispatch(self, robot: str, frame: dict[str, Any] | None,
                  batch: list[tuple[Any, ...]] | None = None) -> None:
        """Book one reply (the scheduler's part)."""
        raise NotImplementedError

    def fds(self) -> list[int]:
        """The output pipes of the workers still answering: the loop's wait includes them."""
        return [fd for fd, wp in self._by_fd.items() if not wp.reader.eof]

    def read_replies(self, timeout: float = 0.0) -> None:
        """Queue the replies that arrived (waiting up to ``timeout`` s for one), in order per
        worker, each with the robot whose request it answers; end of a worker's output, or
        a frame that cannot be read, queues ``None`` (the worker failed)."""
        fds = self.fds()
        if not fds:
            return
        ready, _, _ = select.select(fds, [], [], max(timeout, 0.0))
        for fd in ready:
            wp = self._by_fd[fd]
            reader = wp.reader
            try:
                frames: list[dict[str, Any] | None] = list(reader.read())
            except (OSError, ValueError) as exc:
                log.error("%s: unreadable reply from the learner worker: %s",
                          ", ".join(wp.robots), exc)
                reader.eof = True
                frames = [None]
            else:
                if reader.eof:
                    frames.append(None)
            for f in frames:
                robot = wp.owners.popleft() if wp.owners else wp.robots[0]
                self._replies.append((robot, f))

    def has_replies(self) -> bool:
        """Whether replies were read and not dispatched yet (the loop must not wait)."""
        return bool(self._replies)

    def next_reply(self) -> tuple[str, dict[str, Any] | None] | None:
        """The oldest reply read and not yet dispatched (``None``: none)."""
        return self._replies.popleft() if self._replies else None

    def send(self, robot: str, req: dict[str, Any], ctx: Any) -> None:
        """Send one request; its reply is handled with ``ctx`` (in order)."""
        s = self.slots[robot]
        wp = s.process
        assert wp.proc.stdin is not None
        req["robot"] = robot  # the model it is for, in a process serving several
        try:
            write_frame(wp.proc.stdin, req)
        except (OSError, ValueError) as exc:
            raise WorkerError(self._died(robot, f"cannot send to it ({exc})")) from None
        wp.owners.append(robot)
        s.pending.append((str(req["op"]), ctx))

    def _died(self, robot: str, why: str) -> str:
        wp = self.slots[robot].process
        try:
            code: int | None = wp.proc.wait(1.0)
        except subprocess.TimeoutExpired:
            code = None
        serves = "" if wp.robots == [robot] else f" (serving {', '.join(wp.robots)})"
        return (f"{robot}: learner worker pid {wp.proc.pid}{serves} failed: {why} (exit "
                f"status {code}); stopping the daemon (the write-ahead log holds every "
                "acknowledged pair)")

    def _wait(self, done: Callable[[], bool], what: str, *, timeout_s: float | None = None
              ) -> None:
        limit = self.timeout_s if timeout_s is None else timeout_s
        end = time.monotonic() + limit
        while not done():
            item = self.next_reply()
            if item is None:
                left = end - time.monotonic()
                if not self.fds():  # every worker's end of output was dispatched already
                    raise WorkerError(f"no learner worker left to answer ({what})")
                if left <= 0:
                    raise WorkerError(f"no reply from a learner worker within "
                                      f"{limit:g} s ({what})")
                self.read_replies(left)
                continue
            self._dispatch(*item)

    def close(self, *, kill: bool = False, timeout: float = 10.0) -> None:
        """Stop every worker (``stop`` request, then SIGKILL after ``timeout``)."""
        for wp in self.processes:
            if not kill and wp.proc.poll() is None and wp.proc.stdin is not None:
                try:
                    write_frame(wp.proc.stdin, {"op": "stop"})
                except (OSError, ValueError):
                    pass
            if wp.proc.stdin is not None:
                try:
                    wp.proc.stdin.close()
                except OSError:
                    pass
        end = time.monotonic() + timeout
        for wp in self.processes:
            if not kill:
                try:
                    wp.proc.wait(max(0.1, end - time.monotonic()))
                except subprocess.TimeoutExpired:
                    log.warning("%s: learner worker pid %d did not stop; killed",
                                ", ".join(wp.robots), wp.proc.pid)
            if wp.proc.poll() is None:
                wp.proc.kill()
                wp.proc.wait(5.0)
            if wp.proc.stdout is not None:
                wp.proc.stdout.close()
