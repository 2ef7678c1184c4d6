"""The daemon's transport, behind a narrow interface: Zenoh in production, memory in tests.

The service loop sees only :class:`Transport`: ``subscribe`` (deliveries arrive on another
thread and must only be enqueued), ``publisher`` (one per key, declared once), ``declare_token``
(liveliness), ``stop_intake`` and ``close``. :class:`ZenohTransport` implements it with one
Zenoh session; :class:`roger_daemon.testing.MemoryTransport` is the in-memory fake the unit
tests use.

Session setup (config layering, flags) is :mod:`roger_daemon.zenoh_session`'s; ``open_session``
and ``zenoh_config`` are re-exported here. Zenoh rules followed here (docs/zenoh-notes.md §1,
§3.1 and §4):

- callbacks only copy the payload and push onto the :class:`Inbox`, never call Zenoh, never
  block (``put_nowait``; an overflow is counted);
- payloads larger than the protocol limit are not even copied (``Incoming.payload is None``);
- predictions go out with ``CongestionControl.DROP``, ``express=True`` and
  ``Priority.REAL_TIME``; status with DROP at ``Priority.DATA``;
- the session is closed explicitly (callback subscribers would otherwise keep the
  interpreter from exiting); the daemon never forks after opening it.
"""

from __future__ import annotations

import os
import queue
import select
import threading
import time
import weakref
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

from roger_daemon.zenoh_session import ZenohSettings, open_session, zenoh_config

__all__ = [
    "Inbox",
    "Incoming",
    "LinkEvent",
    "TOKEN_ALIVE",
    "TOKEN_GONE",
    "Publisher",
    "Transport",
    "ZenohTransport",
    "open_session",
    "zenoh_config",
]

ENCODING = "application/msgpack"
#: payloads of :meth:`Transport.watch_tokens`' deliveries: a token appeared, or went
TOKEN_ALIVE = b"alive"
TOKEN_GONE = b"gone"


@dataclass(frozen=True, slots=True)
class Incoming:
    """One received sample, as the callback saw it.

    ``payload`` is ``None`` when the sample was larger than the transport's limit (only its
    ``size`` is kept). ``recv_ns`` is ``time.monotonic_ns()`` (latency), ``recv_wall_ns`` is
    ``time.time_ns()`` (the recorder's log time).
    """

    key: str
    payload: bytes | None
    size: int
    recv_ns: int
    recv_wall_ns: int


Deliver = Callable[[Incoming], None]


@dataclass(frozen=True, slots=True)
class LinkEvent:
    """One transport (a link to a router or a peer) opened (``up``) or closed, to the Zenoh
    node ``zid`` (a ``router``, ``peer`` or ``client``), at ``at_ns`` (monotonic)."""

    up: bool
    zid: str
    whatami: str
    at_ns: int


def _close_fds(*fds: int) -> None:
    for fd in fds:
        os.close(fd)


class Publisher(Protocol):
    """Publishes bytes on one key."""

    def put(self, payload: bytes) -> None:
        """Send one payload (never blocks for long: congestion control DROP)."""


class Transport(Protocol):
    """What the service loop needs from the middleware."""

    def subscribe(self, key_expr: str, deliver: Deliver) -> None:
        """Deliver every sample matching ``key_expr`` (from another thread)."""

    def publisher(self, key: str, *, realtime: bool) -> Publisher:
        """A publisher for ``key``; ``realtime`` selects the prediction QoS."""

    def declare_token(self, key: str) -> None:
        """Declare a liveliness token held until :meth:`close`."""

    def undeclare_token(self, key: str) -> None:
        """Withdraw a token :meth:`declare_token` declared (nothing if it holds none)."""

    def watch_tokens(self, key_expr: str, deliver: Deliver) -> None:
        """Deliver each liveliness token matching ``key_expr`` as it appears (payload
        :data:`TOKEN_ALIVE`) and goes (:data:`TOKEN_GONE`), those alive now included."""

    def alive_tokens(self, key_expr: str, timeout: float) -> list[str]:
        """The keys of the tokens matching ``key_expr`` alive now (waits up to ``timeout``)."""

    def serve(self, key: str, answer: Callable[[], bytes]) -> None:
        """Answer every query on ``key`` with ``answer()`` (called on another thread)."""

    def query(self, key: str, deliver: Deliver, timeout: float) -> None:
        """Ask ``key`` without waiting: each answer is delivered (from another thread); an
        empty payload on ``key`` when none came."""

    def stop_intake(self) -> None:
        """Undeclare every subscriber (first step of shutdown)."""

    def link_events(self) -> list[LinkEvent]:
        """The links opened and closed since the previous call (oldest first)."""

    def close(self) -> None:
        """Release everything; idempotent."""


class Inbox:
    """The bounded hand-over from transport threads to the loop; overflow is counted.

    ``put`` never blocks (it runs on Zenoh's callback threads); ``get`` blocks the loop up to
    a timeout, until an item arrives or one of the given file descriptors (the learner
    workers' pipes) is readable: the loop waits for everything in one ``select`` (a
    self-pipe wakes it for an item), so no thread stands between a worker's reply and the
    loop (docs/fleet.md, *One wait*). Without descriptors (models in the loop) it waits on
    the queue itself, whose wake-up costs no system call of the callback.
    """

    def __init__(self, capacity: int) -> None:
        self._q: queue.Queue[Incoming] = queue.Queue(maxsize=capacity)
        self._lock = threading.Lock()
        self._overflow = 0
        self.capacity = capacity
        self._waiting = False  # the loop is (about to be) in select: put must wake it
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._close_fds = weakref.finalize(self, _close_fds, self._wake_r, self._wake_w)

    def put(self, item: Incoming) -> None:
        """Enqueue without blocking; count an overflow when full."""
        try:
            self._q.put_nowait(item)
        except queue.Full:
            with self._lock:
                self._overflow += 1
            return
        if self._waiting:
            try:
                os.write(self._wake_w, b"\0")
            except OSError:  # full (a wake is pending anyway) or closed
                pass

    def get(self, timeout: float, fds: Sequence[int] = ()) -> Incoming | None:
        """The next item, waiting up to ``timeout`` seconds; ``None`` when none came (the
        time ran out or one of ``fds`` became readable)."""
        try:
            if not fds:  # nothing else to wait for: the queue's own wait wakes fastest
                return self._q.get(timeout=timeout) if timeout > 0 else self._q.get_nowait()
            return self._q.get_nowait()
        except queue.Empty:
            if timeout <= 0 or not fds:
                return None
        self._waiting = True  # before the second look: a put after it writes the wake byte
        try:
            if self._q.empty():
                select.select([self._wake_r, *fds], [], [], timeout)
        finally:
            self._waiting = False
        try:
            while os.read(self._wake_r, 4096):
                pass
        except BlockingIOError:
            pass
        try:
            return self._q.get_nowait()
        except queue.Empty:
            return None

    def close(self) -> None:
        """Release the wake pipe (idempotent; also done when the inbox is collected). Call
        it after the transport closed: a late ``put`` no longer writes to the pipe."""
        self._waiting = False
        self._close_fds()

    @property
    def overflow(self) -> int:
        """How many items were dropped because the inbox was full."""
        with self._lock:
            return self._overflow

    def __len__(self) -> int:
        return self._q.qsize()


# --- Zenoh ---------------------------------------------------------------------------------


class _ZenohPublisher:
    def __init__(self, pub: Any) -> None:
        self._pub = pub

    def put(self, payload: bytes) -> None:
        self._pub.put(payload)


class ZenohTransport:
    """One Zenoh session; open it only after any fork (never fork after this)."""

    def __init__(self, settings: ZenohSettings, *, max_payload_bytes: int) -> None:
        import zenoh

        self._zenoh = zenoh
        self._max = max_payload_bytes
        self.session = open_session(settings)
        self._subs: list[Any] = []
        self._pubs: list[Any] = []
        self._tokens: list[Any] = []
        self._token_keys: list[str] = []
        self._closed = False
        self._links: deque[LinkEvent] = deque(maxlen=1024)
        put = zenoh.SampleKind.PUT

        def on_transport(ev: Any) -> None:
            # a Zenoh thread: record it, nothing else (docs/zenoh-notes.md §3.1)
            self._links.append(LinkEvent(ev.kind == put, str(ev.transport.zid),
                                         str(ev.transport.whatami).lower(),
                                         time.monotonic_ns()))

        self._listener = self.session.info.declare_transport_events_listener(
            on_transport, history=True)

    def subscribe(self, key_expr: str, deliver: Deliver) -> None:
        """Deliver every sample matching ``key_expr`` (from Zenoh's callback threads)."""
        zenoh = self._zenoh
        limit = self._max
        put_kind = zenoh.SampleKind.PUT

        def on_sample(sample: Any) -> None:
            # Runs on a Zenoh callback thread: copy, stamp, enqueue; nothing else.
            recv_ns = time.monotonic_ns()
            wall_ns = time.time_ns()
            if sample.kind != put_kind:
                return
            zb = sample.payload
            size = len(zb)
            data = zb.to_bytes() if size <= limit else None
            deliver(Incoming(str(sample.key_expr), data, size, recv_ns, wall_ns))

        sub = self.session.declare_subscriber(
            key_expr, on_sample, allowed_origin=zenoh.Locality.REMOTE
        )
        self._subs.append(sub)

    def publisher(self, key: str, *, realtime: bool) -> Publisher:
        """A publisher for ``key``; ``realtime`` selects the prediction QoS."""
        zenoh = self._zenoh
        pub = self.session.declare_publisher(
            key,
            encoding=zenoh.Encoding(ENCODING),
            congestion_control=zenoh.CongestionControl.DROP,
            priority=zenoh.Priority.REAL_TIME if realtime else zenoh.Priority.DATA,
            express=realtime,
        )
        self._pubs.append(pub)
        return _ZenohPublisher(pub)

    def declare_token(self, key: str) -> None:
        """Declare a liveliness token held until :meth:`close`."""
        self._tokens.append(self.session.liveliness().declare_token(key))
        self._token_keys.append(key)

    def undeclare_token(self, key: str) -> None:
        """Withdraw the token of ``key`` (nothing if this transport holds none)."""
        if key not in self._token_keys:
            return
        i = self._token_keys.index(key)
        token = self._tokens.pop(i)
        self._token_keys.pop(i)
        try:
            token.undeclare()
        except Exception:  # the session is closing
            pass

    def watch_tokens(self, key_expr: str, deliver: Deliver) -> None:
        """Deliver token appearances and departures (from Zenoh's callback threads)."""
        put_kind = self._zenoh.SampleKind.PUT

        def on_sample(sample: Any) -> None:  # copy and enqueue only (module doc)
            data = TOKEN_ALIVE if sample.kind == put_kind else TOKEN_GONE
            deliver(Incoming(str(sample.key_expr), data, len(data), time.monotonic_ns(),
                             time.time_ns()))

        self._subs.append(self.session.liveliness().declare_subscriber(
            key_expr, on_sample, history=True))

    def alive_tokens(self, key_expr: str, timeout: float) -> list[str]:
        """The keys of the tokens matching ``key_expr`` alive now (a liveliness query)."""
        replies = self.session.liveliness().get(key_expr, timeout=timeout)
        return [str(r.ok.key_expr) for r in replies if r.ok is not None]

    def serve(self, key: str, answer: Callable[[], bytes]) -> None:
        """A queryable on ``key``: each query is answered with ``answer()``, on Zenoh's
        thread (``answer`` reads files only: standby_sync.history)."""

        def on_query(query: Any) -> None:
            query.reply(key, answer())

        self._pubs.append(self.session.declare_queryable(key, on_query))

    def query(self, key: str, deliver: Deliver, timeout: float) -> None:
        """A query on ``key``; its answers are delivered as they come (no size limit), and an
        empty payload on ``key`` when the query ends without one."""
        answered = []

        def on_reply(reply: Any) -> None:  # copy and enqueue only (module doc)
            if reply.ok is None:
                return
            answered.append(True)
            data = reply.ok.payload.to_bytes()
            deliver(Incoming(str(reply.ok.key_expr), data, len(data), time.monotonic_ns(),
                             time.time_ns()))

        def on_end() -> None:
            if not answered:
                deliver(Incoming(key, b"", 0, time.monotonic_ns(), time.time_ns()))

        self.session.get(key, self._zenoh.handlers.Callback(on_reply, on_end), timeout=timeout)

    def stop_intake(self) -> None:
        """Undeclare every subscriber (first step of shutdown)."""
        subs, self._subs = self._subs, []
        for sub in subs:
            try:
                sub.undeclare()
            except Exception:  # already closed with the session
                pass

    def link_events(self) -> list[LinkEvent]:
        """The links opened and closed since the previous call (Zenoh's transport events;
        the ones open at the start come first)."""
        out = []
        while self._links:
            out.append(self._links.popleft())
        return out

    def close(self) -> None:
        """Undeclare everything and close the session; idempotent."""
        if self._closed:
            return
        self._closed = True
        self.stop_intake()
        for obj in (*self._tokens, *self._pubs, self._listener):
            try:
                obj.undeclare()
            except Exception:
                pass
        self._tokens, self._pubs = [], []
        try:
            self.session.close()
        except Exception:  # ZError on timeout: nothing more to do on the way out
            pass
