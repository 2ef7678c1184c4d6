"""One robot's health level from its status: OK, WARN, ERROR or STALE, computed here only.

The daemon computes ``OK``/``WARN``/``ERROR`` for every status it publishes (``info.level``,
with the reasons in ``info.level_reasons``) and logs every change of level (a warning or an
error, so that ``journalctl -p warning`` shows it); ``STALE`` is an observer's verdict (``roger
status``, ``roger list``): no status for :attr:`Thresholds.stale_periods` status periods.
Counters are judged by their change since the previous status, so an old incident does not
keep a robot in WARN forever; the latency percentile covers the last 1000 predictions.

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
inbox overflow since the previous status              WARN
missed 30 Hz ticks since the previous status          WARN
latency p99 >= 100 ms                                 WARN
no perception for 5 s (also: none yet after 5 s up)   WARN
no status for 3 status periods                        STALE
====================================================  =======
"""

from __future__ import annotations

import logging
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

    def assess(self, counters: Mapping[str, Any], now_ns: int) -> tuple[str, str]:
        """``(level, reasons)`` from a status's ``dropped``, ``ticks``, latency and ``info``.

        ``counters`` is the status as a map (``Status.to_map()``): the daemon's counters are
        read from its top level and from ``info``.
        """
        th = self.thresholds
        info = counters.get("info", {})
        found: list[tuple[str, str]] = []

        def grew(name: str, value: int) -> int:
            before = self._prev.get(name, 0)
            self._prev[name] = value
            return value - before

        for name in ERROR_COUNTERS:
            n = grew(name, int(info.get(name, 0)))
            if n > 0:
                found.append(("ERROR", f"{n} {name.replace('_', ' ')}"))
        dropped = grew("dropped", int(counters.get("dropped", 0)))
        if dropped > 0:
            found.append(("ERROR" if dropped > th.drops_error else "WARN",
                          f"{dropped} pairs dropped (queue full)"))
        for name, text in WARN_COUNTERS.items():
            n = grew(name, int(info.get(name, 0)))
            if n > 0:
                found.append(("WARN", f"{text} {n}"))
        p99 = float(counters.get("latency_ms_p99", 0.0))
        if p99 >= th.latency_warn_ms:
            found.append(("ERROR" if p99 >= th.latency_error_ms else "WARN",
                          f"latency p99 {p99:.0f} ms"))
        found += self._input(int(counters.get("ticks", 0)), now_ns)
        found += _states(info)
        self.last = (worst([lv for lv, _ in found]),
                     "; ".join(text for _, text in found)[:MAX_REASONS_CHARS])
        return self.last

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
