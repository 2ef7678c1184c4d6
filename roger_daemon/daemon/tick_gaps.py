"""Perceptions lost in transport, from the gaps in a robot's tick numbers (issue 55).

A sender numbers its perceptions by tick, one per tick (``protocols/README.md``), so a jump of
the tick from ``t`` to ``t + k`` (``k > 1``) means ``k - 1`` perceptions never reached the
daemon (a link down, a router restarted, the daemon stopped while Zenoh's queues overflowed):
they are counted in ``lost`` (status ``info.lost_in_transport``) and logged, at WARNING for the
first gap and for every gap of a second or more (30 ticks), else at DEBUG. The pairs of those
ticks are lost with them. The same tick again (a re-sent perception) or an older one within
``window`` ticks changes nothing; a tick more than ``window`` ticks back is a sender that
started again, and counting resumes from it (docs/zenoh-notes.md §8).

>>> g = TickGaps("r", window=64)
>>> for tick in (0, 1, 2, 6, 6, 7, 0, 1):
...     g.see(tick)
>>> g.lost
3
"""

from __future__ import annotations

import logging

__all__ = ["LONG_GAP", "TickGaps"]

log = logging.getLogger("roger_daemon.daemon.robot")

#: A gap of this many ticks or more is always logged at WARNING (one second at 30 Hz).
LONG_GAP = 30


class TickGaps:
    """The newest tick seen of one robot's perceptions and the ticks skipped before it."""

    def __init__(self, robot: str, window: int) -> None:
        self.robot = robot
        self.window = window
        self.lost = 0
        self.newest: int | None = None
        self._warned = False

    def see(self, tick: int) -> None:
        """Take one perception's tick; count the ticks skipped before it."""
        newest = self.newest
        if newest is None or tick > newest + 1 or tick < newest - self.window:
            self.newest = tick
        elif tick == newest + 1:
            self.newest = tick
            return
        if newest is None:
            return
        if tick < newest - self.window:
            log.info("%s: tick %d after %d: the sender started again", self.robot, tick, newest)
            return
        if tick <= newest:
            return  # re-sent or late: the newest stays
        n = tick - newest - 1
        self.lost += n
        level = logging.WARNING if n >= LONG_GAP or not self._warned else logging.DEBUG
        self._warned = True
        log.log(level, "%s: %d perception%s lost in transport (ticks %d to %d never arrived; "
                "%d in all, status info.lost_in_transport)", self.robot, n,
                "" if n == 1 else "s", newest + 1, tick - 1, self.lost)
