"""What the daemon knows of its links and of its own stalls (issue 55, docs/zenoh-notes.md §8).

* :class:`~roger_daemon.transport.LinkEvent`: one Zenoh transport (a link to a router or a
  peer) opened or closed, as Zenoh's transport events listener reported it
  (:meth:`~roger_daemon.transport.ZenohTransport.link_events`).
* :class:`LinkWatch`: the loop's view, updated at each round of status: which links are up,
  how many closed (``link_downs``), when the daemon last had no link at all and for how long
  (``link_outage_s``); every change logged (down at WARNING, up at INFO); and the daemon's own
  stalls: a round of status that comes more than :data:`STALL_S` late means the loop did not
  run meanwhile (the process was stopped, e.g. SIGSTOP, or starved), counted in
  ``loop_stalls``.

After an outage or a stall the latency windows are emptied: the predictions answered across
it measured the outage, not the daemon (the status would otherwise blame "latency p99" for
the next 1000 predictions); the level names the cause instead (``roger_daemon.daemon.health``).
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from dataclasses import dataclass, field

from roger_daemon.transport import LinkEvent

__all__ = ["STALL_S", "LinkWatch"]

log = logging.getLogger(__name__)

#: A round of status this much later than due (s) is a stall of the loop (a status period is
#: 1 s by default; a busy loop holds a round back by a quarter of a period at most).
STALL_S = 2.0


@dataclass
class LinkWatch:
    """The links and stalls the status reports (the module doc)."""

    up: dict[str, str] = field(default_factory=dict)  # zid -> whatami
    downs: int = 0
    stalls: int = 0
    last_stall_s: float = 0.0
    outage_since_ns: int | None = None  # no link at all since (None: some link is up)
    last_outage_s: float = 0.0
    #: when the last outage began (monotonic ns): each robot's health says the WARN/ERROR
    #: since then again when a link returns
    outage_began_ns: int | None = None
    _seen_any: bool = False
    _last_round_ns: int | None = None

    def apply(self, events: Iterable[LinkEvent]) -> bool:
        """Take the transport events since the previous round; log each change. Whether a
        link came back after the daemon had none."""
        returned = False
        for ev in events:
            if ev.up:
                was_empty = not self.up
                self.up[ev.zid] = ev.whatami
                if self._seen_any and was_empty:
                    outage = self._end_outage(ev.at_ns)
                    log.info("link up: %s %s (after %.1f s without a link)", ev.whatami,
                             ev.zid, outage)
                    returned = True
                else:
                    log.info("link up: %s %s", ev.whatami, ev.zid)
                self._seen_any = True
            elif ev.zid in self.up:
                del self.up[ev.zid]
                self.downs += 1
                if not self.up:
                    self.outage_since_ns = ev.at_ns
                log.warning("link down: %s %s (%d link%s left); what is published meanwhile "
                            "reaches nobody there", ev.whatami, ev.zid, len(self.up),
                            "" if len(self.up) == 1 else "s")
        return returned

    def _end_outage(self, now_ns: int) -> float:
        start = self.outage_since_ns if self.outage_since_ns is not None else now_ns
        self.last_outage_s = (now_ns - start) / 1e9
        self.outage_since_ns = None
        self.outage_began_ns = start
        return self.last_outage_s

    def round(self, now_ns: int, period_ns: int) -> float:
        """A round of status starts at ``now_ns`` (due every ``period_ns``): the stall it
        ends, in seconds (0.0 when the loop kept up)."""
        last, self._last_round_ns = self._last_round_ns, now_ns
        if last is None:
            return 0.0
        late = (now_ns - last - period_ns) / 1e9
        if late < STALL_S:
            return 0.0
        stalled = (now_ns - last) / 1e9
        self.stalls += 1
        self.last_stall_s = stalled
        log.warning("the daemon's loop did not run for %.1f s (the process was stopped or "
                    "starved); the input of that time was queued or lost (status "
                    "info.lost_in_transport)", stalled)
        return stalled

    def info(self, now_ns: int) -> dict[str, object]:
        """The status's link fields (``protocols/README.md``, status ``info``)."""
        outage = self.last_outage_s
        if self.outage_since_ns is not None:
            outage = (now_ns - self.outage_since_ns) / 1e9
        return {"link_state": "up" if self.up else ("down" if self._seen_any else "none"),
                "links": len(self.up), "link_downs": self.downs,
                "link_outage_s": round(outage, 3), "loop_stalls": self.stalls,
                "loop_stall_s": round(self.last_stall_s, 3)}
