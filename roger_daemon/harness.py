"""Run a real daemon subprocess and talk to it over Zenoh on loopback (tests and benchmarks).

- :func:`free_port`: a free TCP port on 127.0.0.1, so every test gets its own Zenoh endpoint;
- :func:`write_config`: a daemon TOML file for that endpoint (multicast scouting off);
- :class:`DaemonProcess`: ``python -m roger_daemon daemon --config ...`` with its stderr in a
  file, waiting for the "ready" log line;
- :class:`Client`: a Zenoh peer connected to the daemon that sends perception/action/control
  and collects predictions and status with their receive times.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from protocols import Action, Control, Perception, Prediction, Status, decode, encode, keys
from protocols.aibo import DIMS as AIBO_DIMS
from protocols.messages import Dims

__all__ = ["Client", "DaemonProcess", "Received", "free_port", "interruptible_child",
           "write_config"]


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _toml(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str | Path):
        return json.dumps(str(value))
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return repr(value)


@contextmanager
def interruptible_child() -> Iterator[None]:
    """Around starting a child that will be sent SIGINT (Ctrl-C): the child gets SIGINT's
    default disposition, whatever this process has. A shell's background job (``cmd &``
    without job control) ignores SIGINT, its descendants inherit that, and a Python child
    started with SIGINT ignored never installs its ``KeyboardInterrupt`` handler: Ctrl-C
    would then do nothing to it. A handled signal is reset to the default on ``exec``, so the
    parent handles SIGINT (the interpreter's own handler) while the child starts. Main
    thread only (``signal.signal``)."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def write_config(
    path: Path,
    *,
    port: int,
    workdir: Path,
    daemon: Mapping[str, Any] | None = None,
    zenoh: Mapping[str, Any] | None = None,
    checkpoint: Mapping[str, Any] | None = None,
    recording: Mapping[str, Any] | None = None,
    robots: Sequence[Mapping[str, Any]] = ({"id": "aibo"},),
    learner: Mapping[str, Any] | None = None,
) -> Path:
    """Write a daemon config listening on ``tcp/127.0.0.1:<port>``; return its path."""
    tables: dict[str, dict[str, Any]] = {
        "daemon": {"clock": "lockstep", **(daemon or {})},
        "learner": dict(learner or {}),
        "zenoh": {"listen": [f"tcp/127.0.0.1:{port}"], "multicast_scouting": False,
                  **(zenoh or {})},
        "checkpoint": {"dir": workdir / "checkpoints", "every_updates": 0, "every_s": 0.0,
                       **(checkpoint or {})},
        "recording": {"enabled": False, "dir": workdir / "recordings", **(recording or {})},
    }
    lines = []
    for name, table in tables.items():
        lines.append(f"[{name}]")
        lines += [f"{k} = {_toml(v)}" for k, v in table.items()]
        lines.append("")
    for robot in robots:
        lines.append("[[robots]]")
        lines += [f"{k} = {_toml(v)}" for k, v in robot.items()]
        lines.append("")
    path.write_text("\n".join(lines), encoding="utf-8")
    return path


class DaemonProcess:
    """``python -m roger_daemon daemon`` as a subprocess (stderr captured in a file)."""

    def __init__(self, config: Path, *, args: Iterable[str] = (), log: Path | None = None,
                 env: Mapping[str, str] | None = None, cwd: Path | None = None) -> None:
        self.log_path = log or config.with_suffix(".log")
        self._log = open(self.log_path, "ab")  # closed in wait()/kill()
        full_env = {**os.environ, "ROGER_LOG_LEVEL": "INFO", "RUST_LOG": "error", **(env or {})}
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "roger_daemon", "daemon", "--config", str(config), *args],
            stdout=self._log, stderr=subprocess.STDOUT, env=full_env, cwd=cwd,
        )

    def log(self) -> str:
        """The process's output so far."""
        return self.log_path.read_text(encoding="utf-8", errors="replace")

    def wait_for_log(self, text: str, timeout: float = 30.0) -> None:
        """Wait until ``text`` appears in the log (raise with the log if the process died)."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if text in self.log():
                return
            if self.proc.poll() is not None:
                raise RuntimeError(f"daemon exited with {self.proc.returncode}:\n{self.log()}")
            time.sleep(0.05)
        raise TimeoutError(f"{text!r} not in the daemon log after {timeout} s:\n{self.log()}")

    def wait_ready(self, timeout: float = 120.0) -> None:
        """Wait until the daemon logs that it is ready."""
        self.wait_for_log(" ready: ", timeout)

    def terminate(self, timeout: float = 10.0,
                  sig: signal.Signals = signal.SIGTERM) -> tuple[int, float]:
        """SIGTERM (or ``sig``); return (exit code, seconds until exit).

        A process still running ``timeout`` seconds after the signal is killed (SIGKILL): the
        exit code is then ``-9`` and no daemon is left behind (a benchmark reports it; it
        used to stop on ``TimeoutExpired`` with the daemon still running)."""
        t0 = time.monotonic()
        self.proc.send_signal(sig)
        try:
            code = self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.kill()
            code = self.proc.returncode
        self._log.close()
        return code, time.monotonic() - t0

    def kill(self) -> None:
        """Kill the process (SIGKILL) if it still runs, and close its log."""
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(10)
        self._log.close()


@dataclass(frozen=True)
class Received:
    """A decoded message and the client's ``time.monotonic_ns()`` at receipt."""

    msg: Any
    recv_ns: int


class Client:
    """A Zenoh session that plays robot + demonstrator for one robot and listens to the daemon."""

    def __init__(self, connect: str, *, robot: str = "aibo", dims: Dims = AIBO_DIMS,
                 mode: str = "peer", daemon_id: str = "roger") -> None:
        import zenoh

        from roger_daemon.zenoh_session import ZenohSettings, open_session

        self.zenoh = zenoh
        self.session = open_session(ZenohSettings(
            mode=mode, connect=(connect,), listen=None if mode == "client" else ()))
        self.robot, self.dims, self.daemon_id = robot, dims, daemon_id
        self.predictions: list[Received] = []
        self.statuses: list[Received] = []
        self.errors: list[str] = []
        self._cond = threading.Condition()
        self.session.declare_subscriber(keys.prediction(robot), self._on("prediction"))
        self.session.declare_subscriber(keys.status(robot), self._on("status"))
        # BLOCK: a test or benchmark feed must not lose its own messages (the daemon's
        # outputs use DROP); on loopback the daemon always drains, so put() never waits long.
        self._cc = zenoh.CongestionControl.BLOCK
        self._pubs = {
            kind: self.session.declare_publisher(
                keys.key(robot, kind), congestion_control=self._cc,
                priority=zenoh.Priority.REAL_TIME, express=True,
            )
            for kind in ("perception", "action", "control")
        }

    def _on(self, kind: str) -> Any:
        sink = self.predictions if kind == "prediction" else self.statuses

        def callback(sample: Any) -> None:
            now = time.monotonic_ns()
            try:
                msg = decode(kind, sample.payload.to_bytes(), dims=self.dims, robot=self.robot)
            except Exception as exc:  # a test asserts that this list stays empty
                self.errors.append(f"{kind}: {exc}")
                return
            with self._cond:
                sink.append(Received(msg, now))
                self._cond.notify_all()

        return callback

    # --- sending -----------------------------------------------------------------------------

    def put(self, kind: str, payload: bytes, robot: str | None = None) -> None:
        """Publish a payload of ``kind`` for this robot (or another ``robot``)."""
        if robot is None or robot == self.robot:
            self._pubs[kind].put(payload)
        else:
            self.session.put(keys.key(robot, kind), payload, congestion_control=self._cc)

    def perception(self, tick: int, x: np.ndarray) -> int:
        """Publish perception(tick); return the send time (monotonic ns)."""
        t = time.monotonic_ns()
        self.put("perception", encode(Perception(self.robot, tick, tick / 30.0, x=x)))
        return t

    def action(self, tick: int, y: np.ndarray, label: str = "") -> None:
        """Publish an action for ``tick``."""
        self.put("action", encode(Action(self.robot, tick, tick / 30.0, y=y, label=label)))

    def control(self, op: str, mode: str = "") -> None:
        """Publish a control message (``op`` ``mode`` or ``reset``)."""
        self.put("control", encode(Control(self.robot, 0, 0.0, op=op, mode=mode)))

    # --- waiting -----------------------------------------------------------------------------

    def wait_daemon(self, timeout: float = 60.0) -> None:
        """Wait until the daemon's liveliness token is visible (link and declarations up)."""
        end = time.monotonic() + timeout
        key = keys.daemon_liveliness(self.daemon_id)
        while time.monotonic() < end:
            replies = self.session.liveliness().get(key, timeout=1.0)
            if any(r.ok is not None for r in replies):
                time.sleep(0.2)  # let our own subscriptions reach the daemon too
                return
            time.sleep(0.1)
        raise TimeoutError(f"daemon token {key} not seen within {timeout} s")

    def wait_prediction(self, tick: int, timeout: float = 60.0) -> Received:
        """Wait for the prediction of ``tick`` (raise ``TimeoutError`` after ``timeout`` s)."""
        end = time.monotonic() + timeout
        with self._cond:
            while True:
                for r in reversed(self.predictions):
                    if r.msg.tick == tick:
                        return r
                left = end - time.monotonic()
                if left <= 0:
                    raise TimeoutError(f"no prediction for tick {tick} within {timeout} s")
                self._cond.wait(left)

    def wait_status(self, predicate: Any = None, timeout: float = 60.0) -> Status:
        """The first status received from now on that satisfies ``predicate``."""
        end = time.monotonic() + timeout
        with self._cond:
            seen = len(self.statuses)
            while True:
                for r in self.statuses[seen:]:
                    if predicate is None or predicate(r.msg):
                        st: Status = r.msg
                        return st
                seen = len(self.statuses)
                left = end - time.monotonic()
                if left <= 0:
                    last = self.statuses[-1].msg.to_map() if self.statuses else None
                    raise TimeoutError(f"no matching status within {timeout} s; last: {last}")
                self._cond.wait(left)

    def predictions_since(self, t_ns: int) -> list[Prediction]:
        """The predictions received at or after ``t_ns`` (``time.monotonic_ns``)."""
        with self._cond:
            return [r.msg for r in self.predictions if r.recv_ns >= t_ns]

    def close(self) -> None:
        """Close the Zenoh session."""
        self.session.close()
