"""Process plumbing of the experiment: ports, child processes, process groups; the jobs built
from them are :mod:`simulator.experiment.jobs`.

A job is what deployment runs, in miniature: ``roger sim`` (lockstep), a controller (``roger
hcc`` as demonstrator or transitioner, or ``roger experiment dpa``), and where needed ``roger
daemon`` (predict mode, resumed from a checkpoint) or ``roger record``. Every job listens on
its own free loopback ports, multicast scouting is off in every process, and nothing connects
to the conventional port 7447 (another daemon may be running there). Each process writes its
output to a log file in the job's directory; a job that fails raises :class:`JobError` with
the tail of the logs.

Topology (explicit endpoints, no gossip needed): the daemon or recorder listens on port A, the
simulator listens on B and connects to A; the controller connects to A and B. The simulator
starts its first episode once ``--wait-peers`` peers are connected.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, NoReturn

from roger_daemon.harness import free_port as _free_port

__all__ = [
    "CHILDREN",
    "Children",
    "JobError",
    "ProcessGroup",
    "child_env",
    "count_episodes",
    "free_port",
    "roger_argv",
    "stop_children_on_signals",
]


_PORT_LOCK = threading.Lock()
_PORTS_USED: set[int] = set()
_EPISODE_LINE = re.compile(r"roger\.sim: episode \d+ location")


def free_port() -> int:
    """A free loopback port not handed out before in this process."""
    with _PORT_LOCK:
        for _ in range(100):
            p = _free_port()
            if p not in _PORTS_USED:
                _PORTS_USED.add(p)
                return p
    raise RuntimeError("no free loopback port found")


def roger_argv(*args: str) -> list[str]:
    """``roger ARGS`` with this interpreter (works without the console script on PATH)."""
    return [sys.executable, "-m", "roger_daemon", *args]


def child_env(extra: Mapping[str, str] | None = None) -> dict[str, str]:
    """Environment of every child: INFO logs, quiet Zenoh (each ``roger`` child pins its own
    BLAS to one thread: roger_daemon/blas.py)."""
    env = dict(os.environ)
    env.update(
        {
            "ROGER_LOG_LEVEL": "INFO",
            "RUST_LOG": "error",
            "PYTHONUNBUFFERED": "1",
        }
    )
    env.pop("JOURNAL_STREAM", None)
    env.pop("INVOCATION_ID", None)
    env.pop("NOTIFY_SOCKET", None)
    env.update(extra or {})
    return env


class JobError(RuntimeError):
    """A job's processes failed; the message carries the tails of their logs."""


class Children:
    """Every child process the experiment has running, so that a stop reaches them all.

    Job threads start and reap their own processes; on SIGTERM or Ctrl-C the command calls
    :meth:`stop_all` (``simulator.experiment.goal_scoring.run``), which refuses new starts and
    terminates what runs, instead of leaving the jobs' simulators, controllers and daemons
    running after the experiment has gone.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._live: set[subprocess.Popen[bytes]] = set()
        self.stopping = False
        self._main_spawning = 0  # the main thread is starting a child and tracking it
        self._deferred: int | None = None  # a stop signalled meanwhile

    @contextmanager
    def spawning(self) -> Iterator[None]:
        """Around starting a child and tracking it. Python runs signal handlers in the main
        thread, between any two of its bytecodes: a SIGTERM that arrived after ``Popen``
        forked but before the child was tracked used to leave that child running after the
        command had exited. A stop signalled while the main thread is in here is carried out
        on the way out, once the child is tracked (:meth:`on_signal`)."""
        main = threading.current_thread() is threading.main_thread()
        if main:
            self._main_spawning += 1
        try:
            yield
        finally:
            if main:
                self._main_spawning -= 1
                if not self._main_spawning and self._deferred is not None:
                    signum, self._deferred = self._deferred, None
                    self.stop_for(signum)

    def on_signal(self, signum: int, _frame: Any = None) -> None:
        """The SIGTERM / SIGINT handler (:func:`stop_children_on_signals`): stop every child
        and exit, or, while the main thread starts one (:meth:`spawning`), once it has."""
        if self._main_spawning:
            self._deferred = signum
            return
        self.stop_for(signum)

    def stop_for(self, signum: int) -> NoReturn:
        """Stop every tracked child, then leave as the signal asks: ``KeyboardInterrupt``
        for SIGINT, else ``SystemExit(128 + signum)`` (143 for SIGTERM)."""
        self.stop_all()
        if signum == signal.SIGINT:
            raise KeyboardInterrupt
        raise SystemExit(128 + signum)

    def add(self, popen: subprocess.Popen[bytes]) -> None:
        """Track ``popen`` (terminated at once if a stop has begun)."""
        with self._lock:
            self._live.add(popen)
            stopping = self.stopping
        if stopping:
            popen.terminate()

    def discard(self, popen: subprocess.Popen[bytes]) -> None:
        """Stop tracking ``popen`` (it has been reaped)."""
        with self._lock:
            self._live.discard(popen)

    def stop_all(self, grace: float = 10.0) -> int:
        """SIGTERM every tracked child, KILL those still running after ``grace`` seconds;
        returns how many were running."""
        with self._lock:
            self.stopping = True
            live = [p for p in self._live if p.poll() is None]
        for p in live:
            p.terminate()
        end = time.monotonic() + grace
        for p in live:
            try:
                p.wait(max(0.0, end - time.monotonic()))
            except subprocess.TimeoutExpired:
                p.kill()
        return len(live)


#: the experiment's children (one process, one registry)
CHILDREN = Children()


def stop_children_on_signals() -> None:
    """SIGTERM and Ctrl-C stop every tracked child before the command exits (143, 130);
    without this the simulators, controllers and daemons of running jobs outlive it."""

    signal.signal(signal.SIGTERM, CHILDREN.on_signal)
    signal.signal(signal.SIGINT, CHILDREN.on_signal)


@dataclass
class _Proc:
    name: str
    popen: subprocess.Popen[bytes]
    log: Path
    handle: IO[bytes]


class ProcessGroup:
    """Subprocesses of one job; :meth:`close` stops whatever still runs (SIGTERM, then KILL)."""

    def __init__(self, workdir: Path, env: Mapping[str, str] | None = None) -> None:
        self.workdir = workdir
        self.env = child_env(env)
        self.procs: dict[str, _Proc] = {}

    def start(self, name: str, argv: Sequence[str]) -> _Proc:
        """Start process ``name`` with its output in ``WORKDIR/NAME.log``."""
        if CHILDREN.stopping:
            raise JobError(f"not starting {name}: the experiment is stopping")
        log = self.workdir / f"{name}.log"
        handle = open(log, "wb")
        with CHILDREN.spawning():  # a stop signalled meanwhile finds it tracked
            popen = subprocess.Popen(
                list(argv), stdout=handle, stderr=subprocess.STDOUT, env=self.env,
                stdin=subprocess.DEVNULL,
            )
            CHILDREN.add(popen)
            proc = _Proc(name, popen, log, handle)
            self.procs[name] = proc
        return proc

    def log_text(self, name: str) -> str:
        """Process ``name``'s log so far ('' if unreadable)."""
        try:
            return self.procs[name].log.read_text(encoding="utf-8", errors="replace")
        except OSError:
            return ""

    def wait_for_log(self, name: str, text: str, timeout: float) -> None:
        """Wait until ``text`` is in the log of ``name``; raise if it exits or time runs out."""
        proc = self.procs[name]
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if text in self.log_text(name):
                return
            if proc.popen.poll() is not None:
                raise JobError(f"{name} exited with {proc.popen.returncode}" + self.tails())
            time.sleep(0.05)
        raise JobError(f"{name}: {text!r} not logged within {timeout:.0f} s" + self.tails())

    def wait(self, name: str, timeout: float) -> int:
        """Wait for ``name`` to exit; raise :class:`JobError` on timeout."""
        try:
            return self.procs[name].popen.wait(timeout)
        except subprocess.TimeoutExpired:
            raise JobError(f"{name} still running after {timeout:.0f} s" + self.tails()) from None

    def stop(self, name: str, timeout: float = 15.0) -> int:
        """SIGTERM ``name`` (if still running) and wait; KILL after ``timeout``."""
        p = self.procs[name].popen
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
            try:
                return p.wait(timeout)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(10)
                raise JobError(f"{name} did not stop on SIGTERM; killed" + self.tails()) from None
        return int(p.returncode)

    def tails(self, lines: int = 15) -> str:
        """The last ``lines`` lines of every process's log, for an error message."""
        out = []
        for name in self.procs:
            text = self.log_text(name).strip().splitlines()[-lines:]
            out.append(f"\n--- {name} ({self.procs[name].log}) ---\n" + "\n".join(text))
        return "".join(out)

    def close(self) -> None:
        """Kill what still runs and close the logs."""
        for proc in self.procs.values():
            if proc.popen.poll() is None:
                proc.popen.send_signal(signal.SIGTERM)
        for proc in self.procs.values():
            try:
                proc.popen.wait(10)
            except subprocess.TimeoutExpired:
                proc.popen.kill()
                proc.popen.wait(10)
            CHILDREN.discard(proc.popen)
            proc.handle.close()


def count_episodes(sim_log: Path) -> int:
    """Episodes the simulator has finished so far, from its INFO log lines."""
    try:
        text = sim_log.read_text(encoding="utf-8", errors="replace")
    except OSError:
        return 0
    return len(_EPISODE_LINE.findall(text))
