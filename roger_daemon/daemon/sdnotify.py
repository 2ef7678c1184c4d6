"""The systemd notify protocol (sd_notify(3)), in a few lines and without a dependency.

Messages are newline-separated ``KEY=VALUE`` datagrams sent to the AF_UNIX socket named by
``$NOTIFY_SOCKET`` (a leading ``@`` means the abstract namespace). Outside systemd (no
``NOTIFY_SOCKET``) every call is a no-op. The watchdog is enabled by ``$WATCHDOG_USEC`` (and,
if set, ``$WATCHDOG_PID`` must be this process); :meth:`Notifier.watchdog` pings at half the
interval and is meant to be called from the main loop only, after a cycle that made progress.
Start-up work that can outlast the unit's ``TimeoutStartSec`` (compiling the learner's kernels
on a cold cache, re-learning logged pairs) runs inside :meth:`Notifier.starting`, which asks
for more time (``EXTEND_TIMEOUT_USEC``) while it runs (docs/zenoh-notes.md §7).
"""

from __future__ import annotations

import logging
import os
import socket
import threading
from collections.abc import Iterator, Mapping
from contextlib import contextmanager

__all__ = ["Notifier"]

log = logging.getLogger(__name__)


class Notifier:
    """Sends READY/STATUS/WATCHDOG/STOPPING to systemd when it is listening."""

    def __init__(self, address: str | None, watchdog_usec: int | None = None) -> None:
        self._addr: str | bytes | None = None
        self._sock: socket.socket | None = None
        if address:
            self._addr = ("\0" + address[1:]) if address.startswith("@") else address
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
        self.watchdog_ns = watchdog_usec * 1000 if watchdog_usec else None
        self._last_ping_ns: int | None = None
        self._failed = False

    @classmethod
    def from_env(cls, env: Mapping[str, str] | None = None) -> Notifier:
        """Read ``NOTIFY_SOCKET``, ``WATCHDOG_USEC`` and ``WATCHDOG_PID``."""
        env = os.environ if env is None else env
        usec: int | None = None
        try:
            usec = int(env.get("WATCHDOG_USEC", "")) or None
        except ValueError:
            usec = None
        pid = env.get("WATCHDOG_PID")
        if pid and pid != str(os.getpid()):
            usec = None
        return cls(env.get("NOTIFY_SOCKET") or None, usec)

    @property
    def enabled(self) -> bool:
        """Whether the process runs under systemd with a notify socket."""
        return self._sock is not None

    def send(self, *fields: str) -> bool:
        """Send ``KEY=VALUE`` fields in one datagram; False if not under systemd or on error."""
        if self._sock is None or self._addr is None:
            return False
        data = "\n".join(f.replace("\n", " ") for f in fields).encode("utf-8")
        try:
            self._sock.sendto(data, self._addr)
        except OSError as exc:
            if not self._failed:
                log.warning("sd_notify to %r failed: %s", self._addr, exc)
                self._failed = True
            return False
        return True

    def ready(self, status: str = "") -> bool:
        """Start-up is complete (session open, models loaded)."""
        return self.send("READY=1", *([f"STATUS={status}"] if status else []))

    def status(self, text: str) -> bool:
        """Free text for ``systemctl status``."""
        return self.send(f"STATUS={text}")

    def stopping(self, status: str = "") -> bool:
        """Shutdown has begun."""
        return self.send("STOPPING=1", *([f"STATUS={status}"] if status else []))

    def extend_start(self, seconds: float) -> bool:
        """Ask for ``seconds`` more of start-up time (``EXTEND_TIMEOUT_USEC``, systemd 236 or
        later): past ``TimeoutStartSec`` the start fails only if no further such message comes
        within ``seconds``."""
        return self.send(f"EXTEND_TIMEOUT_USEC={max(1, round(seconds * 1e6))}")

    @contextmanager
    def starting(self, status: str, *, every_s: float = 5.0,
                 extend_s: float = 30.0) -> Iterator[None]:
        """Around a long but finite start-up phase: send ``STATUS=status``, then from a
        helper thread ask for ``extend_s`` more seconds at once and every ``every_s`` seconds
        until the block ends (:meth:`extend_start`). Only the time limit moves: a start that
        hangs elsewhere (opening the Zenoh session) still fails at ``TimeoutStartSec``. Outside
        systemd it does nothing."""
        if not self.enabled:
            yield
            return
        self.status(status)
        done = threading.Event()

        def keep_extending() -> None:
            while True:
                self.extend_start(extend_s)
                if done.wait(every_s):
                    return

        helper = threading.Thread(target=keep_extending, name="sd-notify-extend", daemon=True)
        helper.start()
        try:
            yield
        finally:
            done.set()
            helper.join()

    def watchdog(self, now_ns: int) -> bool:
        """Ping ``WATCHDOG=1`` if at least half the watchdog interval passed since the last."""
        if self.watchdog_ns is None or self._sock is None:
            return False
        if self._last_ping_ns is not None and now_ns - self._last_ping_ns < self.watchdog_ns // 2:
            return False
        self._last_ping_ns = now_ns
        return self.send("WATCHDOG=1")

    def close(self) -> None:
        """Close the notify socket."""
        if self._sock is not None:
            self._sock.close()
            self._sock = None
