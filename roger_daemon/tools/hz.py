"""``roger hz KEY``: the rate of messages on a key expression, like ``ros2 topic hz``.

Every ``--every`` seconds prints the rate over the last ``--window`` messages (mean period,
min, max and standard deviation of the intervals, in milliseconds); ``--json`` prints one JSON
object per report. A key expression that matches several keys (``'aibo/*'``) gets one line per
key, then the total. Rates are measured from the receive times here, so they include the
network's and this process's jitter. Stops after ``--duration`` seconds or Ctrl-C; gives up
with exit 1 if no message arrived within ``--timeout`` seconds (0: wait for ever; ``--json``
then prints ``{"key": ..., "messages": 0, ...}``).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import deque
from typing import Any

import numpy as np

from roger_daemon.tools.common import (
    Listener,
    add_connection_args,
    count,
    dumps,
    key_expr,
    open_from_args,
    seconds,
)


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roger hz``."""
    parser.add_argument("key", metavar="KEY",
                        help="key expression, e.g. roger/aibo/prediction ('roger/' may be left "
                             "out)")
    parser.add_argument("--window", type=count, default=100, metavar="N",
                        help="rate over the last N messages (default: 100)")
    parser.add_argument("--every", type=seconds, default=1.0, metavar="S",
                        help="print a report every S seconds (default: 1)")
    parser.add_argument("--duration", type=seconds, default=0.0, metavar="S",
                        help="stop after S seconds (default: run until Ctrl-C)")
    parser.add_argument("--json", action="store_true", help="one JSON object per report")
    add_connection_args(parser)


def report(times: deque[float], total: int) -> dict[str, Any] | None:
    """Rate and interval statistics of the receive times in ``times`` (None: < 2 of them)."""
    if len(times) < 2:
        return None
    gaps = np.diff(np.fromiter(times, float)) * 1e3
    mean = float(gaps.mean())
    return {"rate_hz": 1e3 / mean if mean > 0 else float("inf"), "mean_ms": mean,
            "min_ms": float(gaps.min()), "max_ms": float(gaps.max()),
            "std_ms": float(gaps.std()), "window": len(times), "messages": total}


class Rates:
    """Receive times per key and in all (the windows :func:`report` reads)."""

    def __init__(self, window: int) -> None:
        self.window = max(window, 2)
        self.all: deque[float] = deque(maxlen=self.window)
        self.by_key: dict[str, deque[float]] = {}
        self.counts: dict[str, int] = {}
        self.total = 0

    def add(self, key: str, t: float) -> None:
        """One message on ``key`` received at ``t``."""
        self.all.append(t)
        self.by_key.setdefault(key, deque(maxlen=self.window)).append(t)
        self.counts[key] = self.counts.get(key, 0) + 1
        self.total += 1

    def reports(self, pattern: str) -> list[tuple[str, dict[str, Any] | None]]:
        """``(key, report)`` per key (when several keys matched), then the total."""
        out: list[tuple[str, dict[str, Any] | None]] = []
        if len(self.by_key) > 1:
            out += [(k, report(self.by_key[k], self.counts[k])) for k in sorted(self.by_key)]
        return [*out, (pattern, report(self.all, self.total))]


def run(args: argparse.Namespace) -> int:
    """Report until done; 1 if nothing arrived (within ``--timeout``, when it is not 0)."""
    key = key_expr(args.key)
    session = open_from_args(args)
    listener = Listener(session, key)
    rates = Rates(args.window)
    start = time.monotonic()
    next_report = start + max(args.every, 0.1)
    timed_out = False
    try:
        while not args.duration or time.monotonic() - start < args.duration:
            if args.timeout and not rates.total and time.monotonic() - start >= args.timeout:
                timed_out = True
                break
            s = listener.get(min(0.1, max(next_report - time.monotonic(), 0.0)))
            if s is not None:
                rates.add(s.key, s.recv_s)
            if time.monotonic() >= next_report:
                next_report += max(args.every, 0.1)
                for k, rep in rates.reports(key):
                    _print(rep, args.json, k)
    finally:
        listener.close()
        session.close()
    if rates.total == 0:
        within = f" within {args.timeout:g} s" if timed_out else ""
        if args.json:
            print(dumps({"key": key, "messages": 0, "rate_hz": None,
                         "error": f"no messages{within}"}), flush=True)
        print(f"roger hz: no messages on {key}{within}", file=sys.stderr)
        return 1
    return 0


def _print(rep: dict[str, Any] | None, as_json: bool, key: str) -> None:
    if rep is None:
        if not as_json:
            print(f"{key}: waiting for messages", flush=True)
        return
    if as_json:
        print(dumps({"key": key, **rep}), flush=True)
        return
    print(f"{key}: {rep['rate_hz']:.2f} Hz  interval mean {rep['mean_ms']:.1f} ms  "
          f"min {rep['min_ms']:.1f}  max {rep['max_ms']:.1f}  std {rep['std_ms']:.1f}  "
          f"(window {rep['window']}, {rep['messages']} messages)", flush=True)
