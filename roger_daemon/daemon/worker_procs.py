"""Learner worker processes and their pipes: start, send, read, fail, stop.

The process side of :class:`~roger_daemon.daemon.learners.ProcessLearners` (which schedules
the requests and books the replies): one ``python -m roger_daemon.daemon.worker`` per robot,
started with ``subprocess`` (a fresh interpreter, nothing forked after Zenoh opened),
``--nice`` lower than the loop, each with one reader thread that hands its replies, in order,
to a queue and wakes the loop. A request's context waits in ``WorkerSlot.pending`` until its
reply is dispatched; every blocking wait has a deadline (docs/fleet.md, *Failure*).
"""

from __future__ import annotations

import logging
import queue
import subprocess
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from roger_daemon.daemon.robot import RobotRuntime
from roger_daemon.daemon.worker import read_frame, write_frame

if TYPE_CHECKING:
    from roger_daemon.daemon.learners import RemoteModel

__all__ = ["WorkerError", "WorkerProcesses", "WorkerSlot"]

log = logging.getLogger(__name__)


class WorkerError(RuntimeError):
    """A learner worker died, failed or did not answer in time."""


@dataclass
class WorkerSlot:
    """One robot's worker: its process, the requests in flight (op and context, in order)
    and the scheduler's state for it."""

    rt: RobotRuntime
    proc: subprocess.Popen[bytes]
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
    thread: threading.Thread | None = None


class WorkerProcesses:
    """One worker process per robot, its pipe and its reader thread.

    Parameters
    ----------
    robots
        The runtimes to start a worker for (robot id -> runtime).
    timeout_s
        Deadline of every blocking wait for a worker (start, snapshot, drain).
    nice
        How much lower the workers' CPU priority is than the loop's (``[daemon]
        worker_nice``): the loop and Zenoh's threads publish before learning runs.
    """

    def __init__(self, robots: Mapping[str, RobotRuntime], *, timeout_s: float = 120.0,
                 nice: int = 0) -> None:
        self.timeout_s = timeout_s
        self.nice = nice
        self._replies: queue.SimpleQueue[tuple[str, dict[str, Any] | None]] = \
            queue.SimpleQueue()
        self._wake: Callable[[], None] = lambda: None
        self.slots: dict[str, WorkerSlot] = {}
        try:
            for robot, rt in robots.items():  # start them all first: they import in parallel
                proc = subprocess.Popen([sys.executable, "-m", "roger_daemon.daemon.worker",
                                         "--nice", str(nice)],
                                        stdin=subprocess.PIPE, stdout=subprocess.PIPE)
                reader = threading.Thread(target=self._read, args=(robot, proc), daemon=True,
                                          name=f"roger-worker-{robot}")
                self.slots[robot] = WorkerSlot(rt, proc, thread=reader)
                reader.start()
        except BaseException:
            self.close(kill=True)
            raise

    def _dispatch(self, robot: str, frame: dict[str, Any] | None,
                  batch: list[tuple[Any, ...]] | None = None) -> None:
        """Book one reply (the scheduler's part)."""
        raise NotImplementedError

    def _read(self, robot: str, proc: subprocess.Popen[bytes]) -> None:
        assert proc.stdout is not None
        while True:
            try:
                frame = read_frame(proc.stdout)
            except (OSError, ValueError) as exc:
                log.error("%s: unreadable reply from the learner worker: %s", robot, exc)
                frame = None
            self._replies.put((robot, frame))
            self._wake()
            if frame is None or "fatal" in frame:
                return

    def send(self, robot: str, req: dict[str, Any], ctx: Any) -> None:
        """Send one request; its reply is handled with ``ctx`` (in order)."""
        s = self.slots[robot]
        assert s.proc.stdin is not None
        try:
            write_frame(s.proc.stdin, req)
        except (OSError, ValueError) as exc:
            raise WorkerError(self._died(robot, f"cannot send to it ({exc})")) from None
        s.pending.append((str(req["op"]), ctx))

    def _died(self, robot: str, why: str) -> str:
        s = self.slots[robot]
        try:
            code: int | None = s.proc.wait(1.0)
        except subprocess.TimeoutExpired:
            code = None
        return (f"{robot}: learner worker pid {s.proc.pid} failed: {why} (exit status "
                f"{code}); stopping the daemon (the write-ahead log holds every acknowledged "
                "pair)")

    def _wait(self, done: Callable[[], bool], what: str) -> None:
        end = time.monotonic() + self.timeout_s
        while not done():
            left = end - time.monotonic()
            try:
                if left <= 0:
                    raise queue.Empty
                item = self._replies.get(timeout=left)
            except queue.Empty:
                raise WorkerError(f"no reply from a learner worker within {self.timeout_s:g} s "
                                  f"({what})") from None
            self._dispatch(*item)

    def close(self, *, kill: bool = False, timeout: float = 10.0) -> None:
        """Stop every worker (``stop`` request, then SIGKILL after ``timeout``)."""
        for s in self.slots.values():
            if not kill and s.proc.poll() is None and s.proc.stdin is not None:
                try:
                    write_frame(s.proc.stdin, {"op": "stop"})
                except (OSError, ValueError):
                    pass
            if s.proc.stdin is not None:
                try:
                    s.proc.stdin.close()
                except OSError:
                    pass
        end = time.monotonic() + timeout
        for robot, s in self.slots.items():
            if not kill:
                try:
                    s.proc.wait(max(0.1, end - time.monotonic()))
                except subprocess.TimeoutExpired:
                    log.warning("%s: learner worker pid %d did not stop; killed", robot,
                                s.proc.pid)
            if s.proc.poll() is None:
                s.proc.kill()
                s.proc.wait(5.0)
            if s.proc.stdout is not None:
                s.proc.stdout.close()
