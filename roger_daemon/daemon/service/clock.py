"""The service loop's time sources (a fake one in unit tests)."""

from __future__ import annotations

import time
from typing import Protocol

__all__ = ["Clock", "RealClock"]


class Clock(Protocol):
    """Time sources: ``monotonic_ns`` for deadlines and latency, ``time_ns`` for stamps."""

    def monotonic_ns(self) -> int:
        """The monotonic clock, in nanoseconds."""

    def time_ns(self) -> int:
        """The wall clock, in nanoseconds since the epoch."""


class RealClock:
    """The process's clocks."""

    monotonic_ns = staticmethod(time.monotonic_ns)
    time_ns = staticmethod(time.time_ns)
