"""``roger hz KEY``: the rate of messages on a key expression, like ``ros2 topic hz``.

Every ``--every`` seconds prints the rate over the last ``--window`` messages (mean period,
min, max and standard deviation of the intervals, in milliseconds); ``--json`` prints one JSON
object per report. Rates are measured from the receive times here, so they include the
network's and this process's jitter. Stops after ``--duration`` seconds or Ctrl-C; exits 1 if
no message arrived at all.
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


def run(args: argparse.Namespace) -> int:
    """Report until done; 1 if nothing arrived."""
    key = key_expr(args.key)
    session = open_from_args(args)
    listener = Listener(session, key)
    times: deque[float] = deque(maxlen=max(args.window, 2))
    total = 0
    start = time.monotonic()
    next_report = start + max(args.every, 0.1)
    try:
        while not args.duration or time.monotonic() - start < args.duration:
            s = listener.get(min(0.1, max(next_report - time.monotonic(), 0.0)))
            if s is not None:
                times.append(s.recv_s)
                total += 1
            if time.monotonic() >= next_report:
                next_report += max(args.every, 0.1)
                _print(report(times, total), args.json, key)
    finally:
        listener.close()
        session.close()
    if total == 0:
        print(f"roger hz: no messages on {key}", file=sys.stderr)
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
