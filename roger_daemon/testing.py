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

from roger_daemon.transport import (
    TOKEN_ALIVE,
    TOKEN_GONE,
    Deliver,
    Incoming,
    LinkEvent,
    Publisher,
)

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
    #: other sessions' liveliness tokens (:meth:`token`)
    others: list[str] = field(default_factory=list)
    #: the transports whose queryables :meth:`query` reaches, and our own
    peers: list[MemoryTransport] = field(default_factory=list)
    queryables: dict[str, Callable[[], bytes]] = field(default_factory=dict)
    _subs: list[tuple[re.Pattern[str], Deliver]] = field(default_factory=list)
    _watches: list[tuple[re.Pattern[str], Deliver]] = field(default_factory=list)
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

    def undeclare_token(self, key: str) -> None:
        """Forget a recorded liveliness token."""
        if key in self.tokens:
            self.tokens.remove(key)

    def watch_tokens(self, key_expr: str, deliver: Deliver) -> None:
        """Deliver the tokens :meth:`token` injects (and those of :attr:`others` at once)."""
        rx = _key_regex(key_expr)
        self._watches.append((rx, deliver))
        for key in self.others:
            if rx.match(key):
                deliver(Incoming(key, TOKEN_ALIVE, len(TOKEN_ALIVE), self.now_ns(),
                                 time.time_ns()))

    def alive_tokens(self, key_expr: str, timeout: float) -> list[str]:
        """The keys of :attr:`others` (other sessions' tokens) matching ``key_expr``."""
        rx = _key_regex(key_expr)
        return [k for k in self.others if rx.match(k)]

    def token(self, key: str, alive: bool) -> None:
        """Another session's token of ``key`` appeared (``alive``) or went."""
        if alive:
            self.others.append(key)
        elif key in self.others:
            self.others.remove(key)
        data = TOKEN_ALIVE if alive else TOKEN_GONE
        for rx, deliver in self._watches:
            if rx.match(key):
                deliver(Incoming(key, data, len(data), self.now_ns(), time.time_ns()))

    def serve(self, key: str, answer: Callable[[], bytes]) -> None:
        """Answer the queries of the transports linked to this one (:attr:`peers`)."""
        self.queryables[key] = answer

    def query(self, key: str, deliver: Deliver, timeout: float) -> None:
        """Ask the queryables of :attr:`peers` matching ``key``; answers delivered at once
        (an empty payload on ``key`` when none matched)."""
        rx = _key_regex(key)
        answers = [(served, answer) for peer in self.peers
                   for served, answer in peer.queryables.items()
                   if rx.match(served) or served == key]
        for served, answer in answers or [(key, lambda: b"")]:
            data = answer()
            deliver(Incoming(served, data, len(data), self.now_ns(), time.time_ns()))

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
