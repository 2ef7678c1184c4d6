"""The learner benchmark back to back for a while, each run sorted by the host's state (issue 11,
docs/performance.md, *A cross-core probe in the record*).

Runs ``roger bench learner --json --no-unimap`` (the synthetic stream at the paper's
parameters), each in a fresh process, again and again for ``--minutes``, and sorts the runs by
the cross-core round trip their machine record took at the start and at the end
(:func:`roger_daemon.machine.cross_core_ns`): *far apart* when both readings exceed
``--far-ns``, *near* when neither does, *mixed* when they disagree (the host moved the run),
*unknown* without readings (one usable CPU). This project's host has spells with the two vCPUs
on cores far apart, which slow the learner's two threads; one run cannot say how a code fares
through them, a quarter of an hour of runs can. Prints one line per run and a summary per
state (runs, updates/s min / median / max, runs below ``--target``, the worst update p99), or
one JSON object with ``--json``.

    .venv/bin/python scripts/learner_monitor.py [--minutes 15] [--far-ns 250]
        [--target 2000] [--json]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from typing import Any

from roger_daemon.tools.common import count, non_negative

STATES = ("far apart", "near", "mixed", "unknown")
_BENCH = [sys.executable, "-m", "roger_daemon", "bench", "learner", "--json", "--no-unimap"]
_RUN_TIMEOUT_S = 1800  # one run takes seconds; a loaded machine may take minutes


def state_of(start: float | None, end: float | None, far_ns: float) -> str:
    """The host's state over a run from its two cross-core readings (ns).

    >>> state_of(380.0, 410.0, 250), state_of(70.0, 95.0, 250), state_of(70.0, 400.0, 250)
    ('far apart', 'near', 'mixed')
    >>> state_of(None, 80.0, 250)
    'unknown'
    """
    if start is None or end is None:
        return "unknown"
    far = (start > far_ns, end > far_ns)
    return "far apart" if all(far) else "near" if not any(far) else "mixed"


def one_run(far_ns: float, points: int | None = None) -> dict[str, Any]:
    """One benchmark run in a process of its own: its time, rate, p99, state and readings."""
    when = time.strftime("%H:%M:%S")
    bench = _BENCH if points is None else [*_BENCH, "--points", str(points)]
    done = subprocess.run(bench, capture_output=True, text=True, timeout=_RUN_TIMEOUT_S,
                          check=False)
    if done.returncode != 0:
        return {"time": when, "failed": done.returncode, "stderr": done.stderr[-2000:]}
    report = json.loads(done.stdout)
    machine = report["machine"]
    start, end = machine.get("cross_core_ns_start"), machine.get("cross_core_ns_end")
    return {"time": when, "updates_per_s": report["updates_per_s"],
            "update_p99_ms": report["update_p99_ms"], "state": state_of(start, end, far_ns),
            "cross_core_ns": [start, end], "load": [machine["load_avg_1m_start"],
                                                    machine["load_avg_1m_end"]],
            "steal_percent": machine.get("cpu_time", {}).get("steal_percent")}


def summarise(runs: list[dict[str, Any]], target: float) -> dict[str, Any]:
    """Per state, and for every run: the count, updates/s min / median / max, the runs below
    ``target`` and the worst p99; states without runs are left out.

    >>> runs = [{"updates_per_s": r, "update_p99_ms": 1.0, "state": s}
    ...         for r, s in ((2500.0, "near"), (1900.0, "far apart"), (2100.0, "far apart"))]
    >>> far = summarise(runs, 2000)["far apart"]
    >>> far["runs"], far["median"], far["below_target"], sorted(summarise(runs, 2000))
    (2, 2000.0, 1, ['all', 'far apart', 'near'])
    """
    out: dict[str, Any] = {}
    ok = [r for r in runs if "failed" not in r]
    for label in ("all", *STATES):
        chosen = [r for r in ok if label == "all" or r["state"] == label]
        if not chosen:
            continue
        rates = [r["updates_per_s"] for r in chosen]
        out[label] = {"runs": len(chosen), "min": min(rates),
                      "median": statistics.median(rates), "max": max(rates),
                      "below_target": sum(rate < target for rate in rates),
                      "worst_p99_ms": max(r["update_p99_ms"] for r in chosen)}
    return out


def _line(run: dict[str, Any]) -> str:
    if "failed" in run:
        return f"{run['time']}  failed (exit {run['failed']})"
    start, end = run["cross_core_ns"]
    return (f"{run['time']}  {run['updates_per_s']:8.1f} updates/s  p99 "
            f"{run['update_p99_ms']:5.2f} ms  cross-core {start} -> {end} ns  {run['state']}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=non_negative, default=15.0,
                        help="keep running this long (default 15; 0: one run)")
    parser.add_argument("--far-ns", type=non_negative, default=250.0,
                        help="a round trip above this is far apart (default 250)")
    parser.add_argument("--target", type=non_negative, default=2000.0,
                        help="updates/s a run should reach (default 2000)")
    parser.add_argument("--points", type=count, default=None,
                        help="points each run learns (default: the whole stream)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args()  # a bad number: argparse names it and exits 2
    runs: list[dict[str, Any]] = []
    end = time.monotonic() + 60.0 * args.minutes
    while True:
        runs.append(one_run(args.far_ns, args.points))
        if not args.json:
            print(_line(runs[-1]), flush=True)
        if time.monotonic() >= end:
            break
    report = {"far_ns": args.far_ns, "target": args.target, "runs": runs,
              "failed": sum("failed" in r for r in runs),
              "summary": summarise(runs, args.target)}
    if args.json:
        json.dump(report, sys.stdout, indent=1)
        print()
    else:
        for label, s in report["summary"].items():
            print(f"{label:9}  {s['runs']:4d} runs  {s['min']:8.1f} / {s['median']:8.1f} / "
                  f"{s['max']:8.1f} updates/s (min / median / max)  below {args.target:g}: "
                  f"{s['below_target']}  worst p99 {s['worst_p99_ms']} ms")
    return 1 if report["failed"] else 0


if __name__ == "__main__":
    raise SystemExit(main())
