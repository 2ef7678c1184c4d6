"""Test doubles shipped with the package, for the tests of ``roger_daemon`` and of the
packages built on it: :class:`MemoryTransport`, an in-memory
:class:`~roger_daemon.transport.Transport` (inject samples, inspect publications) that runs
the service loop without Zenoh.

Integration tests use real Zenoh sessions on 127.0.0.1; this fake is for unit tests only.
"""

from __future__ import annotations

import re
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from roger_daemon.transport import Deliver, Incoming, LinkEvent, Publisher

__all__ = ["MemoryTransport"]


def _key_regex(key_expr: str) -> re.Pattern[str]:
    """``*`` (one chunk) and ``**`` (any number of chunks); neither matches a verbatim ``@``."""
    chunk = r"[^/@][^/]*"
    pattern = ""
    for i, c in enumerate(key_expr.split("/")):
        sep = "/" if i else ""
        if c == "**":
            pattern += f"(?:{sep}{chunk})*" if i else f"(?:{chunk}(?:/{chunk})*)?"
        else:
            pattern += sep + (chunk if c == "*" else re.escape(c))
    return re.compile("^" + pattern + "$")


@dataclass
class _MemoryPublisher:
    key: str
    realtime: bool
    sink: list[tuple[str, bytes, bool]]

    def put(self, payload: bytes) -> None:
        self.sink.append((self.key, bytes(payload), self.realtime))


@dataclass
class MemoryTransport:
    """In-memory ``Transport`` for unit tests: inject samples, inspect publications."""

    max_payload_bytes: int = 64 * 1024
    published: list[tuple[str, bytes, bool]] = field(default_factory=list)
    tokens: list[str] = field(default_factory=list)
    closed: bool = False
    intake_stopped: bool = False
    links: list[LinkEvent] = field(default_factory=list)
    _subs: list[tuple[re.Pattern[str], Deliver]] = field(default_factory=list)
    now_ns: Callable[[], int] = time.monotonic_ns

    def subscribe(self, key_expr: str, deliver: Deliver) -> None:
        """Deliver every injected sample matching ``key_expr``."""
        self._subs.append((_key_regex(key_expr), deliver))

    def publisher(self, key: str, *, realtime: bool) -> Publisher:
        """A publisher appending to :attr:`published`."""
        return _MemoryPublisher(key, realtime, self.published)

    def declare_token(self, key: str) -> None:
        """Record a liveliness token."""
        self.tokens.append(key)

    def stop_intake(self) -> None:
        """Forget every subscriber."""
        self.intake_stopped = True
        self._subs = []

    def link_events(self) -> list[LinkEvent]:
        """The events :meth:`link` queued since the previous call."""
        out, self.links[:] = list(self.links), []
        return out

    def link(self, up: bool, zid: str = "r0", whatami: str = "router") -> None:
        """Queue a link event, stamped now (:attr:`now_ns`)."""
        self.links.append(LinkEvent(up, zid, whatami, self.now_ns()))

    def close(self) -> None:
        """Stop intake and mark closed."""
        self.stop_intake()
        self.closed = True

    def inject(self, key: str, payload: bytes) -> int:
        """Deliver ``payload`` on ``key`` to matching subscribers; returns how many matched."""
        n = 0
        size = len(payload)
        data = payload if size <= self.max_payload_bytes else None
        for rx, deliver in self._subs:
            if rx.match(key):
                deliver(Incoming(key, data, size, self.now_ns(), time.time_ns()))
                n += 1
        return n

    def take(self, kind: str | None = None) -> list[tuple[str, bytes]]:
        """Remove and return publications (optionally only keys ending in ``/<kind>``)."""
        keep, out = [], []
        for key, data, rt in self.published:
            if kind is None or key.endswith("/" + kind):
                out.append((key, data))
            else:
                keep.append((key, data, rt))
        self.published[:] = keep
        return out
