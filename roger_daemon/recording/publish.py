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
from roger_daemon.recording.mcapio import LogReader

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


def publish_log(
    session: Any,
    paths: Iterable[str | Path],
    *,
    speed: float = 1.0,
    kinds: Iterable[str] = DEFAULT_KINDS,
    robot: str | None = None,
    should_stop: Callable[[], bool] | None = None,
    progress: Callable[[int], None] | None = None,
) -> PublishStats:
    """Publish the messages of ``paths`` on an open ``zenoh.Session``; see the module doc."""
    import zenoh

    if speed < 0:
        raise ValueError("speed must be >= 0")
    wanted = set(kinds)
    enc = zenoh.Encoding("application/msgpack")
    pubs: dict[str, Any] = {}
    st = PublishStats()
    t_wall0 = time.monotonic()
    t_log0: int | None = None
    last_log = 0
    try:
        for p in paths:
            for lm in LogReader(Path(p)).messages():
                if should_stop is not None and should_stop():
                    return st
                topic = lm.topic
                try:
                    r, kind = keyexpr.parse(topic)
                except ProtocolError:
                    r, kind = "", ""
                if kind not in wanted or (robot is not None and r != robot):
                    st.skipped += 1
                    continue
                lt = lm.message.log_time
                if t_log0 is None:
                    t_log0 = lt
                last_log = max(last_log, lt)
                if speed > 0:
                    due = t_wall0 + (lt - t_log0) / 1e9 / speed
                    wait = due - time.monotonic()
                    if wait > 0:
                        time.sleep(wait)
                    else:
                        st.max_late_s = max(st.max_late_s, -wait)
                pub = pubs.get(topic)
                if pub is None:
                    pub = pubs[topic] = session.declare_publisher(topic, encoding=enc)
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
