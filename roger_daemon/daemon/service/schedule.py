"""The realtime clock's tick schedule: the next deadline, jitter, lateness, missed ticks; and
:class:`QuietWork`, when work that can wait for a quiet moment runs."""

from __future__ import annotations

from dataclasses import dataclass, field

from roger_daemon.daemon.window import Window

__all__ = ["LoopStats", "QuietWork", "TickSchedule"]

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


class QuietWork:
    """Work the loop does at its quiet moments, one piece per cycle, or all of it once it has
    waited ``max_wait_ns`` since it last ran (docs/fleet.md, *Work at quiet moments*): the
    recorders' flushes and the periodic checkpoints. The first call runs (nothing ran yet)."""

    def __init__(self, max_wait_ns: int) -> None:
        self.max_wait_ns = max_wait_ns
        #: set by :meth:`runs`: the work waited ``max_wait_ns``, so all of it goes now
        self.overdue = False
        self._ran_ns: int | None = None

    def runs(self, now: int, quiet: bool) -> bool:
        """Whether the work runs in the cycle at ``now`` (``quiet``: a quiet moment); if it
        does, from ``now`` on it waits again."""
        self.overdue = self._ran_ns is None or now - self._ran_ns >= self.max_wait_ns
        if not (quiet or self.overdue):
            return False
        self._ran_ns = now
        return True
