"""Run a real daemon subprocess and talk to it over Zenoh on loopback (tests and benchmarks).

- :func:`free_port`: a free TCP port on 127.0.0.1, so every test gets its own Zenoh endpoint;
- :func:`write_config`: a daemon TOML file for that endpoint (multicast scouting off);
- :class:`DaemonProcess`: ``python -m roger_daemon daemon --config ...`` with its stderr in a
  file, waiting for the "ready" log line;
- :class:`Client`: :class:`roger_daemon.client.RobotClient` (the robot-side client) with the
  short method names the tests use.
"""

from __future__ import annotations

import json
import os
import random
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from protocols.aibo import DIMS as AIBO_DIMS
from protocols.messages import Dims
from roger_daemon.client import Received, RobotClient

__all__ = ["Client", "DaemonProcess", "Received", "free_port", "interruptible_child",
           "write_config"]


#: where :func:`free_port` looks when the kernel's ephemeral range is unreadable (Linux's default
#: range starts at 32768)
_BELOW_EPHEMERAL = (20000, 32768)


def _ephemeral_low() -> int:
    try:
        low = int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return _BELOW_EPHEMERAL[1]
    return low


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on right now, drawn at random from below the
    kernel's ephemeral range (docs/testing.md, *Ports*): ``bind(0)`` hands out ports of that
    range, which every outgoing connection also takes its local port from, so a port found
    free there could be some process's connection by the time the daemon or simulator it is
    for listens on it ("Address already in use" under load)."""
    low = _ephemeral_low()
    first = _BELOW_EPHEMERAL[0] if low > _BELOW_EPHEMERAL[0] + 1000 else 1024
    draw = random.SystemRandom()
    for _ in range(200):
        port = draw.randrange(first, low) if low > first else 0
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
            return int(s.getsockname()[1])
    raise RuntimeError(f"no free TCP port on 127.0.0.1 in {first}-{low - 1}")


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


class Client(RobotClient):
    """:class:`~roger_daemon.client.RobotClient` with the short names the tests and benchmarks
    use (``perception``, ``action``, ``control``, ``put``)."""

    def __init__(self, connect: str, *, robot: str = "aibo", dims: Dims = AIBO_DIMS,
                 mode: str = "peer", daemon_id: str = "roger") -> None:
        super().__init__(connect, robot=robot, dims=dims, mode=mode, daemon_id=daemon_id)

    def put(self, kind: str, payload: bytes, robot: str | None = None) -> None:
        """Publish a payload of ``kind`` for this robot (or another ``robot``)."""
        self.send_raw(kind, payload, robot)

    def perception(self, tick: int, x: np.ndarray) -> int:
        """Publish perception(tick); return the send time (monotonic ns)."""
        return self.send_perception(tick, x)

    def action(self, tick: int, y: np.ndarray, label: str = "") -> None:
        """Publish an action for ``tick``."""
        self.send_action(tick, y, label)

    def control(self, op: str, mode: str = "") -> None:
        """Publish a control message (``op`` ``mode`` or ``reset``)."""
        self.send_control(op, mode)
