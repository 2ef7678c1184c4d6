"""scripts/fleet_trace.py (docs/fleet.md): the spans it wraps still exist, and its analysis
finds the slow bursts and what overlapped them."""

from __future__ import annotations

import importlib
from pathlib import Path

from script_testing import load_script

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"
MS = 1_000_000


def test_every_span_the_trace_wraps_exists() -> None:
    """A renamed function would silently drop out of the trace: each path must resolve (a
    worker's ``__main__`` is ``roger_daemon.daemon.worker``)."""
    spans = load_script("fleet_spans", SCRIPTS / "fleet_trace" / "fleet_spans.py")
    assert spans.DAEMON and spans.WORKER
    for module, path, _label in (*spans.DAEMON, *spans.WORKER):
        owner = importlib.import_module("roger_daemon.daemon.worker" if module == "__main__"
                                        else module)
        for part in path.split("."):
            owner = getattr(owner, part)
        assert callable(owner), (module, path)


def test_the_analysis_finds_slow_bursts_and_what_overlapped_them() -> None:
    trace = load_script("fleet_trace_script", SCRIPTS / "fleet_trace.py")
    events = []
    for tick in range(20):  # two robots; ticks 0-1 are the warm-up tenth
        t0 = tick * 33 * MS
        last = 12 * MS if tick in (5, 9) else 4 * MS  # two slow bursts
        for robot, done in (("r0", 2 * MS), ("r1", last)):
            events.append(("sent", robot, tick, t0, t0 + MS // 2))
            events.append(("published", robot, tick, t0 + done - MS // 10, t0 + done))
    events.append(("status", "", -1, 5 * 33 * MS + 3 * MS, 5 * 33 * MS + 8 * MS))
    events.append(("status", "", -1, 15 * 33 * MS, 15 * 33 * MS + 5 * MS))  # a fast burst
    report = trace.analyse(events, 10.0)
    assert report["bursts"] == 18 and report["slow_bursts"] == 2
    assert report["slow_with_nothing_else"] == 1
    assert report["slow_overlapping"] == {"status": 1}
    assert report["spans"]["status"]["n"] == 2 and report["spans"]["status"]["max_ms"] == 5.0
