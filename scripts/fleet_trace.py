"""Trace a lockstep fleet run: what the daemon's loop and its learner workers did around every
burst of answers (issue 11; docs/fleet.md, *Status one robot at a time*).

Runs ``roger bench fleet --clock lockstep`` with ``scripts/fleet_trace`` on ``PYTHONPATH``, so
the daemon and its workers time the spans listed in ``scripts/fleet_trace/fleet_spans.py``
(and every prediction from receipt to publication), then prints per span its count, median
and maximum, the bursts whose last answer came later than ``--slow-ms`` after their first
perception, and which spans overlapped those bursts. Timing wraps cost a few microseconds
each: the bench's own figures under a trace are not the benchmark's.

    .venv/bin/python scripts/fleet_trace.py [--robots 8] [--seconds 20] [--slow-ms 10] [--json]
        [-- extra arguments of roger bench fleet, e.g. --set checkpoint.every_updates=200]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
#: spans that are the answers themselves, or too frequent to say anything when they overlap
ANSWERING = {"sent", "published", "step", "worker_predict", "status_robot"}

Event = tuple[str, str, int, int, int]  # (label, robot, tick, start ns, end ns)


def bursts(events: list[Event]) -> list[tuple[int, int, int]]:
    """``(tick, first receipt ns, last publication ns)`` of every tick all of whose robots'
    predictions were sent and published (the first tenth, the warm-up, left out)."""
    sent: dict[int, list[int]] = defaultdict(list)
    published: dict[int, list[int]] = defaultdict(list)
    for label, _robot, tick, start, end in events:
        if label == "sent":
            sent[tick].append(start)  # the perception's receipt
        elif label == "published":
            published[tick].append(end)
    ticks = sorted(t for t in sent if len(published.get(t, ())) == len(sent[t]))
    ticks = ticks[len(ticks) // 10:]
    return [(t, min(sent[t]), max(published[t])) for t in ticks]


def analyse(events: list[Event], slow_ms: float) -> dict[str, Any]:
    """The span table, the slow bursts and what overlapped them."""
    spans: dict[str, list[float]] = defaultdict(list)
    for label, _robot, _tick, start, end in events:
        if label not in ("sent", "published"):
            spans[label].append((end - start) / 1e6)
    table = {label: {"n": len(v), "p50_ms": round(float(np.median(v)), 3),
                     "max_ms": round(float(np.max(v)), 3)} for label, v in sorted(spans.items())}
    other = [(start, end, label) for label, _r, _t, start, end in events
             if label not in ANSWERING and end - start > 300_000]  # > 0.3 ms
    all_bursts = bursts(events)
    overlaps: Counter[str] = Counter()
    slow = alone = 0
    for _tick, first, last in all_bursts:
        if (last - first) / 1e6 <= slow_ms:
            continue
        slow += 1
        hit = {label for start, end, label in other if end >= first - 2_000_000 and start <= last}
        alone += not hit
        overlaps.update(hit)
    answers = [(last - first) / 1e6 for _t, first, last in all_bursts]
    return {"spans": table, "bursts": len(all_bursts),
            "burst_ms_p50": round(float(np.median(answers)), 3) if answers else None,
            "burst_ms_p99": round(float(np.percentile(answers, 99)), 3) if answers else None,
            "slow_ms": slow_ms, "slow_bursts": slow, "slow_with_nothing_else": alone,
            "slow_overlapping": dict(overlaps.most_common())}


def read_events(directory: Path) -> list[Event]:
    """Every process's events, in one list."""
    out: list[Event] = []
    for path in sorted(directory.glob("*.json")):
        out += [tuple(e) for e in json.loads(path.read_text(encoding="utf-8"))]
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--robots", type=int, default=8)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--slow-ms", type=float, default=10.0,
                        help="a burst is slow when its last answer comes later (default 10)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("extra", nargs="*", help="after --: more roger bench fleet arguments")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="roger-fleet-trace-") as tmp:
        env = dict(os.environ, ROGER_FLEET_TRACE_DIR=tmp,
                   PYTHONPATH=os.pathsep.join(p for p in (str(HERE / "fleet_trace"),
                                                          os.environ.get("PYTHONPATH", "")) if p))
        cmd = [sys.executable, "-m", "roger_daemon", "bench", "fleet", "--robots",
               str(args.robots), "--duration", str(args.seconds), "--clock", "lockstep",
               "--json", *args.extra]
        bench = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
        if bench.returncode != 0:
            print(bench.stderr[-2000:], file=sys.stderr)
            return bench.returncode
        report = analyse(read_events(Path(tmp)), args.slow_ms)
    report["bench_summary"] = json.loads(bench.stdout).get("summary", {})
    if args.json:
        print(json.dumps(report, indent=2))
        return 0
    print(f"{report['bursts']} bursts: first perception -> last answer p50 "
          f"{report['burst_ms_p50']} ms, p99 {report['burst_ms_p99']} ms; "
          f"{report['slow_bursts']} over {args.slow_ms:g} ms, "
          f"{report['slow_with_nothing_else']} of them with nothing but the answers")
    for label, n in report["slow_overlapping"].items():
        print(f"  overlapped by {label}: {n}")
    print(f"{'span':20s} {'n':>8s} {'p50 ms':>9s} {'max ms':>9s}")
    for label, row in report["spans"].items():
        print(f"{label:20s} {row['n']:8d} {row['p50_ms']:9.3f} {row['max_ms']:9.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
