"""The realtime clock's tick schedule: the next deadline, jitter, lateness, missed ticks."""

from __future__ import annotations

from dataclasses import dataclass, field

from roger_daemon.daemon.window import Window

__all__ = ["LoopStats", "TickSchedule"]

_MS = 1_000_000


@dataclass
class LoopStats:
    """The loop's own measurements (shown in every robot's status)."""

    jitter_ms: Window = field(default_factory=Window)
    lateness_ms: Window = field(default_factory=Window)
    missed_ticks: int = 0
    published: int = 0


class TickSchedule:
    """Ticks every ``period_ns`` while predictions are published; idle stretches restart it.

    The first tick after an idle stretch starts a fresh schedule; a tick that overran whole
    periods skips them and counts them as missed.
    """

    def __init__(self, period_ns: int, stats: LoopStats) -> None:
        self.period_ns = period_ns
        self.stats = stats
        self.next_tick = 0
        self._last_fire: int | None = None

    def start(self, now: int) -> None:
        """The first deadline, one period from ``now``."""
        self.next_tick = now + self.period_ns

    def fired(self, now: int, published: bool) -> None:
        """Book the tick handled at ``now`` (``published``: it published predictions)."""
        if not published:
            self._last_fire = None
            self.next_tick = max(self.next_tick + self.period_ns, now)
            return
        if self._last_fire is None:
            # First tick after an idle stretch: start a fresh schedule from now.
            self._last_fire = now
            self.next_tick = now + self.period_ns
            return
        self.stats.lateness_ms.add((now - self.next_tick) / _MS)
        self.stats.jitter_ms.add(abs((now - self._last_fire) - self.period_ns) / _MS)
        self._last_fire = now
        self.next_tick += self.period_ns
        if self.next_tick <= now:  # overran whole periods: skip them, count them
            missed = (now - self.next_tick) // self.period_ns + 1
            self.stats.missed_ticks += int(missed)
            self.next_tick += int(missed) * self.period_ns
