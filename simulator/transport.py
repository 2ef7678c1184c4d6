"""Zenoh plumbing shared by ``roger sim`` and ``roger hcc`` (and usable by the experiment).

* :func:`loopback_config`: a peer-mode ``zenoh.Config`` with explicit listen/connect
  endpoints, multicast scouting off, gossip on (docs/zenoh-notes.md §2.2).
* :func:`add_zenoh_args` / :func:`config_from_args`: ``--listen``, ``--connect``,
  ``--zenoh-config``, ``--zenoh-set`` on a command line; session setup itself is
  :mod:`roger_daemon.zenoh_session`'s (``open_session`` is re-exported here).
* :class:`Subscription`: a subscriber whose zenoh callback only appends the sample to a
  bounded deque (the oldest dropped on overflow) and rings the process's :class:`Doorbell`;
  the loop decodes and validates every sample, counting and logging once per kind the ones
  that fail, never raising.
* :func:`wait_for`: the loop sleeps on the doorbell until a sample arrives (no polling: in
  lockstep most of the six or so processes of an episode are waiting at any moment, and on a
  2-core machine polling wake-ups took the CPU the working one needed).
* :class:`StopFlag`: SIGTERM/SIGINT set a flag that the one loop of the process checks.
* :func:`publisher`: a msgpack publisher with ``express=True`` and DROP congestion control
  (a stalled peer never blocks the loop, nor a router's forwarding).

Topology: Zenoh peers do not route for each other (a peer that only *connects* to the
simulator never hears a third peer). Every ROGER process therefore also listens, by default
on an ephemeral loopback port (:data:`EPHEMERAL`); with gossip on, peers learn each other's
locators through the first connection and mesh up by themselves (measured: A listens, B and C
listen on ``tcp/127.0.0.1:0`` and connect to A; C receives B's samples).

Sessions must be opened after any fork; processes are started with ``subprocess``.
"""

from __future__ import annotations

import argparse
import json
import logging
import signal
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Sequence
from pathlib import Path
from types import FrameType
from typing import Any, TypeVar

import zenoh

from protocols import Dims, ProtocolError, decode, encode, keys
from protocols.messages import Message
from roger_daemon.zenoh_session import ZenohSettings, open_session, settings_from_args, zenoh_config
from roger_daemon.zenoh_session import add_zenoh_args as add_session_args

__all__ = [
    "EPHEMERAL",
    "MSGPACK",
    "Doorbell",
    "Subscription",
    "InvalidCounter",
    "StopFlag",
    "add_zenoh_args",
    "config_from_args",
    "episode_publisher",
    "has_subscribers",
    "loopback_config",
    "open_session",
    "publisher",
    "put",
    "serve",
    "wait_for",
]

log = logging.getLogger(__name__)

T = TypeVar("T")

MSGPACK = zenoh.Encoding("application/msgpack")

#: Listen on an ephemeral port, loopback only.
EPHEMERAL = "tcp/127.0.0.1:0"
#: The nodes' Zenoh lease (ms): a vanished peer is noticed within it.
LEASE_MS = 2000


def loopback_config(
    listen: Sequence[str] = (), connect: Sequence[str] = (), lease_ms: int = LEASE_MS
) -> zenoh.Config:
    """Peer mode, the given endpoints only, no multicast scouting, gossip on."""
    return zenoh_config(ZenohSettings(mode="peer", listen=tuple(listen), connect=tuple(connect),
                                      multicast_scouting=False, gossip=True,
                                      lease_ms=int(lease_ms)))


def add_zenoh_args(
    parser: argparse.ArgumentParser, *, listen: Sequence[str] = (), connect: Sequence[str] = ()
) -> None:
    """The Zenoh flags (:func:`roger_daemon.zenoh_session.add_zenoh_args`) with the nodes'
    defaults: a loopback peer, gossip on, a 2 s lease."""
    add_session_args(parser, listen=listen, connect=connect, lease_ms=LEASE_MS, gossip=True)


def config_from_args(args: argparse.Namespace) -> zenoh.Config:
    """The session config a command line asked for."""
    return zenoh_config(settings_from_args(args))


def publisher(session: zenoh.Session, key: str, *,
              priority: zenoh.Priority | None = None) -> zenoh.Publisher:
    """An express msgpack publisher with DROP congestion control: a stalled peer never blocks
    the loop, and no sample of this process ever holds a router's forwarding of the others
    (a BLOCK sample waiting in a router for a busy subscriber stalls everything that process
    sends through it: docs/zenoh-notes.md §4.1, issue 55). ``priority``: Zenoh's default
    (``DATA``) unless given; a priority of its own gives a stream its own send queue."""
    return session.declare_publisher(key, encoding=MSGPACK, express=True,
                                     congestion_control=zenoh.CongestionControl.DROP,
                                     priority=zenoh.Priority.DATA if priority is None
                                     else priority)


def episode_publisher(session: zenoh.Session, robot: str) -> zenoh.Publisher:
    """The simulator's ``episode`` publisher (``roger sim`` and ``roger teach``): DROP like
    every stream of the simulator (a BLOCK event waiting in a router for a busy subscriber
    stalled the perceptions behind it for 5 s: docs/zenoh-notes.md §4.1), at a priority of its
    own so that perceptions never take its send queue's batches."""
    return publisher(session, keys.episode(robot), priority=zenoh.Priority.INTERACTIVE_HIGH)


def has_subscribers(pub: zenoh.Publisher) -> bool:
    """Whether any subscriber matches ``pub``'s key now (zenoh's ``MatchingStatus``; its type
    stub says ``bool``, the object of zenoh 1.10 has ``.matching``: either is read)."""
    status: Any = pub.matching_status
    return bool(getattr(status, "matching", status))


def put(pub: zenoh.Publisher, msg: Message) -> None:
    """Encode and publish one message."""
    pub.put(encode(msg))


class InvalidCounter:
    """Counts rejected payloads by reason; logs the first of each reason (then every 1000th)."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.counts: Counter[str] = Counter()

    def add(self, reason: str, detail: str) -> None:
        """Count one rejected payload of ``reason``; log the first (then every 1000th)."""
        self.counts[reason] += 1
        n = self.counts[reason]
        if n == 1 or n % 1000 == 0:
            log.warning("%s: invalid message #%d (%s): %s", self.name, n, reason, detail)

    def total(self) -> int:
        """How many payloads were rejected."""
        return sum(self.counts.values())


class Doorbell:
    """Rung by subscriber callbacks, waited on by the process's loop (one per process)."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._rings = 0

    @property
    def rings(self) -> int:
        """How many times it has rung (read before polling, then :meth:`wait_after` it)."""
        return self._rings

    def ring(self) -> None:
        """A sample arrived (any thread)."""
        with self._cond:
            self._rings += 1
            self._cond.notify_all()

    def wait_after(self, seen: int, timeout: float) -> None:
        """Return once it has rung more than ``seen`` times, or after ``timeout`` s."""
        with self._cond:
            if self._rings == seen and timeout > 0:
                self._cond.wait(timeout)


#: The doorbell of this process's inboxes (each node runs one loop).
DOORBELL = Doorbell()


class Subscription:
    """A subscription to one message kind of one robot: its decoded, validated messages.

    ``capacity`` bounds the backlog; on overflow the oldest samples are dropped (a lockstep
    peer never has more than a few in flight). Zenoh's callback thread only appends the
    sample and rings ``doorbell``.
    """

    def __init__(
        self,
        session: zenoh.Session,
        robot: str,
        kind: str,
        dims: Dims | None,
        invalid: InvalidCounter,
        capacity: int = 256,
        doorbell: Doorbell = DOORBELL,
    ) -> None:
        self.robot = robot
        self.kind = kind
        self.dims = dims
        self.invalid = invalid
        self.received = 0
        self._samples: deque[zenoh.Sample] = deque(maxlen=capacity)

        def arrived(sample: zenoh.Sample) -> None:
            self._samples.append(sample)  # deque.append is atomic; maxlen drops the oldest
            doorbell.ring()

        self._sub = session.declare_subscriber(keys.key(robot, kind), arrived)

    def poll(self) -> Message | None:
        """The next valid message, or ``None`` when none is waiting (never blocks)."""
        while True:
            try:
                sample = self._samples.popleft()
            except IndexError:
                return None
            self.received += 1
            try:
                robot, kind = keys.parse(str(sample.key_expr))
                if kind != self.kind or robot != self.robot:
                    raise ProtocolError("bad_key", f"unexpected key {sample.key_expr}")
                return decode(kind, sample.payload.to_bytes(), dims=self.dims, robot=robot)
            except ProtocolError as exc:
                self.invalid.add(exc.reason, str(exc))
            except Exception as exc:  # never let a bad sample take the loop down
                self.invalid.add("not_msgpack", f"{type(exc).__name__}: {exc}")

    def drain(self) -> list[Message]:
        """Every valid message waiting now."""
        out = []
        while (m := self.poll()) is not None:
            out.append(m)
        return out

    def close(self) -> None:
        """Undeclare the subscriber."""
        try:
            self._sub.undeclare()
        except Exception:  # already closed with the session
            pass


def wait_for(
    poll: Callable[[], T | None], timeout: float, stop: StopFlag | None = None,
    doorbell: Doorbell = DOORBELL,
) -> T | None:
    """Call ``poll`` until it returns non-``None`` or ``timeout`` seconds pass (then ``None``).

    Between calls it sleeps on ``doorbell`` (rung by every :class:`Subscription` of the process),
    waking at least every 50 ms to check ``stop``.
    """
    deadline = time.monotonic() + timeout
    while True:
        seen = doorbell.rings
        got = poll()
        if got is not None:
            return got
        left = deadline - time.monotonic()
        if (stop is not None and stop.stopped) or left <= 0:
            return None
        doorbell.wait_after(seen, min(left, 0.05))


class StopFlag:
    """Set by SIGTERM/SIGINT (installed in the main thread); checked by the loop."""

    def __init__(self, install: bool = True) -> None:
        self.stopped = False
        self.signal: int | None = None
        if install:
            signal.signal(signal.SIGTERM, self._handle)
            signal.signal(signal.SIGINT, self._handle)

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        self.stopped = True
        self.signal = signum


def serve(
    node: Any, args: argparse.Namespace, *, cleanup: Callable[[], None] | None = None
) -> dict[str, Any]:
    """Open the session from ``args``, run ``node.run(session)`` to its end, close, report.

    The one lifecycle of every ROGER node process: the session is closed whatever happens
    (a close that times out is logged, nothing is left to save then), ``cleanup`` runs after
    it, the node's counters go to ``--stats`` (if given) and, as one JSON line, to stdout.
    """
    session = open_session(config_from_args(args))
    try:
        out: dict[str, Any] = node.run(session)
    finally:
        try:
            session.close()
        except Exception as exc:  # zenoh may time out closing; nothing left to save
            log.warning("closing the zenoh session: %s", exc)
        if cleanup is not None:
            cleanup()
    stats = getattr(args, "stats", None)
    if stats:
        Path(stats).parent.mkdir(parents=True, exist_ok=True)
        Path(stats).write_text(json.dumps(out, indent=1))
    print(json.dumps(out), flush=True)
    return out
