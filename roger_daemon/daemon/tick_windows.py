"""When the loop may send work to its learner workers in the realtime clock.

Two windows around each tick keep the cores free for what the robots wait for
(docs/fleet.md, *Scheduling and fairness* and *The delivery window*):

- the **quiet window** before a tick: no step starts that is not expected back before it
  (its estimated time + 1 ms, at most a quarter of the period), so the loop publishes on time;
- the **delivery window** after a tick that published: no request at all for
  :data:`DELIVERY_WINDOW_NS`, so the predictions reach their robots before the workers wake.

Lockstep has no tick: neither window applies there.
"""

from __future__ import annotations

import time

__all__ = ["DELIVERY_WINDOW_NS", "TickWindows"]

#: how long after a tick that published no request goes to a worker
DELIVERY_WINDOW_NS = 1_500_000


class TickWindows:
    """The realtime tick as the workers' scheduling sees it (``ProcessLearners``)."""

    def __init__(self) -> None:
        self.deadline_ns: int | None = None  # the next realtime tick (None: no timer)
        self.period_ns = 0  # the realtime clock's period
        self.delivery_until_ns = 0  # the end of the delivery window

    def quiet(self, est_ns: int) -> bool:
        """Whether a step taking ``est_ns`` (+ 1 ms) would still run at the next tick; the
        window is at most a quarter of the period, so a slow step (the first ones compile)
        never holds work back for good."""
        window = min(est_ns + 1_000_000, self.period_ns // 4)
        return self.deadline_ns is not None and \
            time.monotonic_ns() + window >= self.deadline_ns

    def ticked(self, now_ns: int, deadline_ns: int, *, published: bool) -> None:
        """The tick fired at ``now_ns`` (the next one is at ``deadline_ns``); if it
        ``published``, the delivery window opens."""
        self.deadline_ns = deadline_ns
        if published:
            self.delivery_until_ns = now_ns + DELIVERY_WINDOW_NS

    def delivering(self) -> bool:
        """Whether the delivery window is open."""
        return time.monotonic_ns() < self.delivery_until_ns

    def wake_ns(self) -> int | None:
        """When the loop must wake to send what the delivery window holds back (``None``:
        no window open)."""
        return self.delivery_until_ns if self.delivering() else None
