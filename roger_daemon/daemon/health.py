"""One robot's health level from its status: OK, WARN, ERROR or STALE, computed here only.

The daemon computes ``OK``/``WARN``/``ERROR`` for every status it publishes (``info.level``,
with the reasons in ``info.level_reasons``) and logs every change of level (a warning or an
error, so that ``journalctl -p warning`` shows it); ``STALE`` is an observer's verdict (``roger
status``, ``roger list``): no status for :attr:`Thresholds.stale_periods` status periods.
Counters are judged by their change since the previous status, so an old incident does not
keep a robot in WARN forever; the latency percentile covers the last 1000 predictions (emptied
after a stall or an outage, whose level names its cause instead: issue 55).

The WARN or ERROR of an outage is said again once a link returns (:meth:`Health.link_returned`):
published while the link was down, it reached nobody; the first status after the link is
back carries at least its level, its reasons after ``while the link was down:`` (the worst
level since :data:`NOTICE_NS` before the outage, its first occurrence; one said again once is
not said after the next outage).

Thresholds (the defaults of :class:`Thresholds`, documented in ``protocols/README.md``):

====================================================  =======
condition                                             level
====================================================  =======
a learn, predict, checkpoint or recording error       ERROR
the disk full (``disk_full``; learning on the log's   ERROR
reserve, or stopped: ``learning_stopped``)
pairs lost at start-up (``recovery_lost_pairs``)      WARN
latency p99 >= 1000 ms                                ERROR
more than 30 pairs dropped since the previous status  ERROR
any pair dropped since the previous status            WARN
more than 30 perceptions lost in transport since      ERROR
the previous status (``info.lost_in_transport``)
any perception lost in transport since then           WARN
no link at all (``info.link_state`` "down")           WARN
a link closed since the previous status               WARN
the daemon's loop stalled since then (``loop_stalls``) WARN
inbox overflow since the previous status              WARN
missed 30 Hz ticks since the previous status          WARN
latency p99 >= 100 ms                                 WARN
no perception for 5 s (also: none yet after 5 s up)   WARN
no status for 3 status periods                        STALE
====================================================  =======
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

__all__ = ["LEVELS", "LOG_LEVEL_OF", "Health", "Thresholds", "is_stale", "worst"]

LEVELS = ("OK", "WARN", "ERROR", "STALE")
#: how the daemon logs a change of level (a WARN or ERROR reaches ``journalctl -p warning``)
LOG_LEVEL_OF = {"OK": logging.INFO, "WARN": logging.WARNING, "ERROR": logging.ERROR,
                "STALE": logging.ERROR}
ERROR_COUNTERS = ("learn_errors", "predict_errors", "checkpoint_errors", "recording_errors")
WARN_COUNTERS = {"inbox_overflow": "inbox overflow", "missed_ticks": "missed ticks"}
MAX_REASONS_CHARS = 256  # a protocol string's limit
#: A WARN or ERROR this long before the last link closed is said again when it returns: Zenoh
#: notices a dead link only after its lease (10 s by default, docs/zenoh-notes.md §5).
NOTICE_NS = 10_000_000_000


@dataclass(frozen=True)
class Thresholds:
    """Where WARN and ERROR begin."""

    latency_warn_ms: float = 100.0
    latency_error_ms: float = 1000.0
    drops_error: int = 30
    no_input_s: float = 5.0
    stale_periods: float = 3.0


def worst(levels: list[str]) -> str:
    """The most severe of ``levels`` (``OK`` for none)."""
    return max(levels, key=LEVELS.index, default="OK")


def is_stale(age_s: float, status_hz: float, thresholds: Thresholds | None = None) -> bool:
    """Whether a status ``age_s`` old means the daemon stopped reporting (level STALE)."""
    th = thresholds or Thresholds()
    return age_s > th.stale_periods / max(status_hz, 1e-9)


@dataclass
class Health:
    """The level of one robot, judged on each status from the change since the previous one."""

    thresholds: Thresholds = field(default_factory=Thresholds)
    _prev: dict[str, int] = field(default_factory=dict)
    _input_ns: int | None = None
    _ticks: int = -1
    last: tuple[str, str] = ("OK", "")
    #: the recent WARN and ERROR assessments but the link's own: (level, reasons, monotonic ns)
    alerts: deque[tuple[str, str, int]] = field(default_factory=lambda: deque(maxlen=16))
    _returned_from_ns: int | None = None
    _heard_ns: int = -1  # when the outage's WARN/ERROR was last said again (on a live link)

    def link_returned(self, since_ns: int) -> None:
        """A link came back after an outage that began at ``since_ns``: the next assessment
        says the worst WARN/ERROR of it again."""
        self._returned_from_ns = since_ns

    def assess(self, counters: Mapping[str, Any], now_ns: int) -> tuple[str, str]:
        """``(level, reasons)`` from a status's ``dropped``, ``ticks``, latency and ``info``.

        ``counters`` is the status as a map (``Status.to_map()``): the daemon's counters are
        read from its top level and from ``info``.
        """
        info = counters.get("info", {})
        found = self._counters(counters, info)
        found += self._input(int(counters.get("ticks", 0)), now_ns)
        said = self._said_again(now_ns)
        if found:  # what went wrong here, not the link's state: what to say again
            self.alerts.append((worst([lv for lv, _ in found]),
                                "; ".join(t for _, t in found), now_ns))
        found = self._link(info) + _states(info) + found  # states hold while they last
        level, reasons = worst([lv for lv, _ in found]), "; ".join(text for _, text in found)
        if said is not None:
            level = worst([level, said[0]])
            reasons = "; ".join(r for r in (reasons, said[1]) if r)
        self.last = (level, reasons[:MAX_REASONS_CHARS])
        return self.last

    def _grew(self, name: str, value: int) -> int:
        before = self._prev.get(name, 0)
        self._prev[name] = value
        return value - before

    def _counters(self, counters: Mapping[str, Any], info: Mapping[str, Any]
                  ) -> list[tuple[str, str]]:
        """The reasons of the counters that grew, and of the latency."""
        th = self.thresholds
        found: list[tuple[str, str]] = []
        for name in ERROR_COUNTERS:
            n = self._grew(name, int(info.get(name, 0)))
            if n > 0:
                found.append(("ERROR", f"{n} {name.replace('_', ' ')}"))
        for name, where, one, text in (
                ("dropped", counters, "pair", "dropped (queue full)"),
                ("lost_in_transport", info, "perception", "lost in transport")):
            n = self._grew(name, int(where.get(name, 0)))
            if n > 0:
                found.append(("ERROR" if n > th.drops_error else "WARN",
                              f"{n} {one}{'' if n == 1 else 's'} {text}"))
        for name, text in WARN_COUNTERS.items():
            n = self._grew(name, int(info.get(name, 0)))
            if n > 0:
                found.append(("WARN", f"{text} {n}"))
        p99 = float(counters.get("latency_ms_p99", 0.0))
        if p99 >= th.latency_warn_ms:
            found.append(("ERROR" if p99 >= th.latency_error_ms else "WARN",
                          f"latency p99 {p99:.0f} ms"))
        return found

    def _said_again(self, now_ns: int) -> tuple[str, str] | None:
        """The worst WARN/ERROR of the outage once more (the first of that level: the cause
        rather than the silence after it), if a link just returned (:meth:`link_returned`)."""
        since, self._returned_from_ns = self._returned_from_ns, None
        recent = [a for a in self.alerts
                  if since is not None and a[2] >= since - NOTICE_NS and a[2] > self._heard_ns]
        if not recent:
            return None
        self._heard_ns = now_ns  # said on a live link: not again after the next outage
        top = worst([a[0] for a in recent])
        level, reasons, at_ns = next(a for a in recent if a[0] == top)
        return level, (f"while the link was down: {level} {reasons} "
                       f"({(now_ns - at_ns) / 1e9:.0f} s ago)")

    def _link(self, info: Mapping[str, Any]) -> list[tuple[str, str]]:
        """The link and stall reasons (``roger_daemon.daemon.service.link``)."""
        found = []
        if info.get("link_state") == "down":
            found.append(("WARN", f"no link for {float(info.get('link_outage_s', 0)):.0f} s"))
        n = self._grew("link_downs", int(info.get("link_downs", 0)))
        if n > 0:
            found.append(("WARN", f"{n} link{'s' if n > 1 else ''} down"))
        if self._grew("loop_stalls", int(info.get("loop_stalls", 0))) > 0:
            found.append(("WARN", f"daemon stalled {float(info.get('loop_stall_s', 0)):.1f} s"))
        return found

    def _input(self, ticks: int, now_ns: int) -> list[tuple[str, str]]:
        if self._input_ns is None or ticks != self._ticks:
            self._input_ns, self._ticks = now_ns, ticks
            return []
        idle = (now_ns - self._input_ns) / 1e9
        if idle >= self.thresholds.no_input_s:
            return [("WARN", f"no perception for {idle:.0f} s")]
        return []


def _states(info: Mapping[str, Any]) -> list[tuple[str, str]]:
    """Conditions that hold while they last (not changes): a full disk, a lossy start-up
    (docs/durability.md)."""
    found = []
    full = str(info.get("disk_full", ""))
    if full:
        stopped = bool(info.get("learning_stopped", False))
        found.append(("ERROR", f"disk full ({full}): " +
                      ("learning stopped" if stopped else "learning on the log's reserve")))
    lost = int(info.get("recovery_lost_pairs", 0))
    if lost > 0:
        found.append(("WARN", f"{lost} pairs lost at start-up (no intact copy)"))
    return found
