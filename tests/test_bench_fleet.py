"""``roger bench fleet`` end to end: a real daemon, real worker processes, real Zenoh."""

from __future__ import annotations

import json
import subprocess
import sys


def test_bench_fleet_runs_both_phases_against_a_real_daemon() -> None:
    """A short ``roger bench fleet`` (real daemon with two worker processes, real Zenoh on
    loopback): every robot is fed, learns and is answered, and every prediction it received
    decodes (they are validated after the phase, not in Zenoh's callback)."""
    out = subprocess.run(
        [sys.executable, "-m", "roger_daemon", "bench", "fleet", "--robots", "2",
         "--seconds", "2", "--warmup", "1", "--json"],
        capture_output=True, text=True, timeout=240, check=True)
    report = json.loads(out.stdout)
    for clock in ("realtime", "lockstep"):
        phase = report["phases"][clock]
        assert phase["exit_code"] == 0 and phase["decode_errors"] == 0
        assert phase["workers"] == "process"
        assert set(phase["robots"]) == {"r0", "r1"}
        for robot in phase["robots"].values():
            assert robot["predictions_per_s"] > 0 and robot["updates"] > 0
            assert robot["busy_ticks"] >= 0 and robot["fed_per_s"] > 0
            # the daemon's publish stamps: a period, and a delivery that takes time
            assert 0 <= robot["publish_jitter_p99_ms"] < 1000 / 30
            assert 0 < robot["delivery_p50_ms"] <= robot["delivery_p99_ms"] < 1000
    for robot in report["phases"]["lockstep"]["robots"].values():
        assert 0 < robot["latency_p50_ms"] <= robot["latency_p99_ms"]
