"""``roger up``'s supervisor: start the planned processes in order, follow the daemon's status,
stop them in reverse order (the order and stop rules are in :mod:`simulator.launch`)."""

from __future__ import annotations

import logging
import shlex
import signal
import subprocess
import time
from types import FrameType
from typing import IO, TYPE_CHECKING

if TYPE_CHECKING:
    from simulator.launch import Plan

__all__ = ["Supervisor"]

log = logging.getLogger("roger.up")


class Supervisor:
    """Starts the planned processes in order, watches them, stops them in reverse order."""

    def __init__(self, p: Plan) -> None:
        self.p = p
        self.procs: dict[str, subprocess.Popen[bytes]] = {}
        self.logs: list[IO[bytes]] = []
        self.stop_reason = ""
        self.signalled = ""

    def _on_signal(self, signum: int, _frame: FrameType | None) -> None:
        self.signalled = self.stop_reason = signal.Signals(signum).name

    def run(self) -> int:
        """Run the session to its end; 0 when every process stopped cleanly (130 when that
        was after Ctrl-C), else 1."""
        self.p.workdir.mkdir(parents=True, exist_ok=True)
        old = {s: signal.signal(s, self._on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            self._start_all()
            if not self.stop_reason:
                self._supervise()
        finally:
            codes = self._stop_all()
            for s, h in old.items():
                signal.signal(s, h)
        bad = {n: c for n, c in codes.items() if c != 0}
        for name, code in codes.items():
            log.info("%s exited with %s", name, code)
        if bad:
            log.error("not every process stopped cleanly: %s (logs in %s)", bad, self.p.workdir)
            return 1
        log.info("stopped cleanly (%s); logs in %s", self.stop_reason or "done", self.p.workdir)
        # Ctrl-C: 130, as every command interrupted in a terminal (docs/cli.md)
        return 130 if self.signalled == "SIGINT" else 0

    def _start(self, name: str) -> None:
        from simulator.experiment.procs import child_env

        handle = open(self.p.workdir / f"{name}.log", "wb")  # closed in stop
        self.logs.append(handle)
        self.procs[name] = subprocess.Popen(
            self.p.argv[name], stdout=handle, stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL, env=child_env(), start_new_session=True,
            cwd=self.p.workdir)
        log.info("started %s (pid %d): %s", name, self.procs[name].pid,
                 shlex.join(self.p.argv[name][2:]))

    def _start_all(self) -> None:
        self._start("daemon")
        self._wait_daemon()
        for name in [n for n in self.p.argv if n != "daemon"]:
            if self.stop_reason:
                return
            self._start(name)

    def _wait_daemon(self, timeout: float = 120.0) -> None:
        text = b" ready: "
        path = self.p.workdir / "daemon.log"
        end = time.monotonic() + timeout
        while time.monotonic() < end and not self.stop_reason:
            if text in path.read_bytes():
                log.info("daemon ready on %s; watch it with: roger status --watch --connect %s",
                         self.p.daemon_ep, self.p.daemon_ep)
                return
            if self.procs["daemon"].poll() is not None:
                raise RuntimeError(f"the daemon exited with {self.procs['daemon'].returncode}; "
                                   f"see {path}")
            time.sleep(0.1)
        if not self.stop_reason:
            raise RuntimeError(f"the daemon was not ready within {timeout:.0f} s; see {path}")

    def _supervise(self) -> None:
        watch = _DaemonWatch(self.p.daemon_ep)
        try:
            while not self.stop_reason:
                watch.poll()
                for name, proc in self.procs.items():
                    if proc.poll() is None:
                        continue
                    if name == "sim" and proc.returncode == 0:
                        if self.p.exit_when_done:
                            self.stop_reason = "the session is over (the simulator finished)"
                            break
                    elif name == "controller" and proc.returncode == 0:
                        continue  # --exit-when-done: it saw the simulator's end
                    else:
                        self.stop_reason = f"{name} exited with {proc.returncode}"
                        break
                time.sleep(0.2)
            if not self.signalled and self.procs["daemon"].poll() is None:
                self._drain(watch)
        finally:
            watch.close()
        log.info("stopping: %s", self.stop_reason)

    def _drain(self, watch: _DaemonWatch) -> None:
        """Let the daemon learn the pairs still queued (lockstep runs ahead of learning)."""
        end = time.monotonic() + self.p.learn_timeout_s
        start, note = watch.received, time.monotonic()
        while time.monotonic() < end and not self.signalled:
            watch.poll()
            if watch.received > start and not any(watch.queue.values()):
                return
            if self.procs["daemon"].poll() is not None:
                return
            if time.monotonic() >= note:
                note = time.monotonic() + 10.0
                log.info("waiting for the daemon to learn its queued pairs: %s (at most %.0f s "
                         "more; Ctrl-C stops now, the checkpoint keeps them)",
                         ", ".join(f"{r}: {q} pairs or messages waiting, {watch.updates[r]} learned"
                                   for r, q in watch.queue.items()) or "no status yet",
                         end - time.monotonic())
            time.sleep(0.2)
        if not self.signalled:
            log.warning("the daemon still had queued pairs after %.0f s (session.learn_timeout_s);"
                        " they are saved in its final checkpoint", self.p.learn_timeout_s)

    def _stop_all(self) -> dict[str, int | None]:
        codes: dict[str, int | None] = {}
        for name in reversed(list(self.procs)):
            proc = self.procs[name]
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
                try:
                    proc.wait(self.p.stop_timeout_s)
                except subprocess.TimeoutExpired:
                    log.error("%s did not stop within %.0f s of SIGTERM: killed", name,
                              self.p.stop_timeout_s)
                    proc.kill()
                    proc.wait(10)
            codes[name] = proc.returncode
        for handle in self.logs:
            handle.close()
        return codes


class _DaemonWatch:
    """Follows the daemon's status: warns about drops and inbox overflow, keeps queue depths."""

    def __init__(self, endpoint: str) -> None:
        from protocols import keys
        from roger_daemon.tools.common import Listener
        from roger_daemon.zenoh_session import ZenohSettings, open_session

        self.session = open_session(ZenohSettings(listen=(), connect=(endpoint,)))
        self.listener = Listener(self.session, keys.all_of_kind("status"), capacity=64)
        self.seen: dict[str, tuple[int, int]] = {}
        self.queue: dict[str, int] = {}
        self.updates: dict[str, int] = {}
        self.received = 0

    def poll(self) -> None:
        from protocols.errors import ProtocolError
        from roger_daemon.tools.common import decode_sample

        while (s := self.listener.get(0)) is not None:
            try:
                st = decode_sample(s.key, s.payload)
            except ProtocolError:
                continue
            now = (int(st["dropped"]), int(st["info"].get("inbox_overflow", 0)))
            before = self.seen.get(st["robot"], (0, 0))
            if now[0] > before[0] or now[1] > before[1]:
                log.warning("%s: the daemon dropped %d pairs (inbox overflow %d) so far: its "
                            "queue is too small for this session", st["robot"], *now)
            self.seen[st["robot"]] = now
            # pairs still to learn: queued, or not even paired yet (waiting in the inbox)
            self.queue[st["robot"]] = int(st["queue_depth"]) + int(
                st["info"].get("inbox_depth", 0))
            self.updates[st["robot"]] = int(st["updates"])
            self.received += 1

    def close(self) -> None:
        self.listener.close()
        self.session.close()
