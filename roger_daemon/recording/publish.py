"""``roger replay --publish``: re-publish a log on Zenoh, paced by ``log_time``.

Messages go out in file order (the recorder's order) on their recorded key expressions with
their recorded payload bytes. Pacing: message i is sent at ``t0 + (log_time_i - log_time_0) /
speed`` (``speed`` 1 is realtime, 2 twice as fast; 0 sends as fast as possible, which can
overflow a live daemon's drop-oldest queues: the receiver's drop counters tell). A ``log_time``
that goes backwards is sent at once. By default only the inputs of a daemon are re-published
(perception, action, command, episode, control), not the recorded outputs (prediction, status).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from protocols import keys as keyexpr
from protocols.errors import ProtocolError
from roger_daemon.recording.mcapio import LogReader, topics_of

__all__ = ["DEFAULT_KINDS", "PublishStats", "publish_log"]

DEFAULT_KINDS = ("perception", "action", "command", "episode", "control")


@dataclass
class PublishStats:
    """What was re-published."""

    published: int = 0
    skipped: int = 0
    by_topic: dict[str, int] = field(default_factory=dict)
    wall_s: float = 0.0
    log_span_s: float = 0.0
    max_late_s: float = 0.0  # worst lateness against the paced schedule
    subscribers_matched: bool = False  # every publisher had a subscriber when sending began


def _pace(due: float, st: PublishStats, should_stop: Callable[[], bool] | None) -> bool:
    """Sleep until the monotonic time ``due`` (in slices, so that a stop request is seen
    within 0.1 s); record lateness. False if a stop was requested meanwhile."""
    wait = due - time.monotonic()
    if wait <= 0:
        st.max_late_s = max(st.max_late_s, -wait)
    while wait > 0:
        time.sleep(min(wait, 0.1))
        if should_stop is not None and should_stop():
            return False
        wait = due - time.monotonic()
    return True


def publish_log(
    session: Any,
    paths: Iterable[str | Path],
    *,
    speed: float = 1.0,
    kinds: Iterable[str] = DEFAULT_KINDS,
    robot: str | None = None,
    should_stop: Callable[[], bool] | None = None,
    progress: Callable[[int], None] | None = None,
    wait_subscribers_s: float = 0.0,
) -> PublishStats:
    """Publish the messages of ``paths`` on an open ``zenoh.Session``; see the module doc.

    Publishers are declared for every recorded topic first; with ``wait_subscribers_s`` > 0 it
    then waits (up to that long) until each of them has a matching subscriber, so that the
    first messages are not sent into the void.
    """
    import zenoh

    if speed < 0:
        raise ValueError("speed must be >= 0")
    wanted = set(kinds)
    files = [Path(p) for p in paths]
    enc = zenoh.Encoding("application/msgpack")
    st = PublishStats()

    def selected(topic: str) -> bool:
        try:
            r, kind = keyexpr.parse(topic)
        except ProtocolError:
            return False
        return kind in wanted and (robot is None or r == robot)

    topics = {t for p in files for t in topics_of(p) if selected(t)}
    pubs: dict[str, Any] = {t: session.declare_publisher(t, encoding=enc) for t in sorted(topics)}
    deadline = time.monotonic() + wait_subscribers_s
    while pubs and time.monotonic() < deadline and not all(
        pub.matching_status for pub in pubs.values()
    ):
        time.sleep(0.01)
    st.subscribers_matched = all(pub.matching_status for pub in pubs.values()) if pubs else False
    t_wall0 = time.monotonic()
    t_log0: int | None = None
    last_log = 0
    try:
        for p in files:
            for lm in LogReader(Path(p)).messages():
                if should_stop is not None and should_stop():
                    return st
                topic = lm.topic
                pub = pubs.get(topic)
                if pub is None:
                    st.skipped += 1
                    continue
                lt = lm.message.log_time
                if t_log0 is None:
                    t_log0 = lt
                last_log = max(last_log, lt)
                if speed > 0 and not _pace(t_wall0 + (lt - t_log0) / 1e9 / speed, st,
                                           should_stop):
                    return st
                pub.put(lm.message.data)
                st.published += 1
                st.by_topic[topic] = st.by_topic.get(topic, 0) + 1
                if progress is not None:
                    progress(1)
    finally:
        for pub in pubs.values():
            pub.undeclare()
        st.wall_s = time.monotonic() - t_wall0
        st.log_span_s = (last_log - t_log0) / 1e9 if t_log0 is not None else 0.0
    return st
