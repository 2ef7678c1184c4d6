"""``roger bench fleet`` end to end: a real daemon, real worker processes, real Zenoh."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np

from roger_daemon.bench.fleet import period_jitter_ms


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
            # computed from the daemon's publish stamps and the receipts (timings are
            # `roger bench` figures, not test assertions: only their consistency is checked)
            assert math.isfinite(robot["publish_jitter_p99_ms"])
            assert robot["publish_jitter_p99_ms"] >= 0 and robot["jitter_p99_ms"] >= 0
            assert 0 < robot["delivery_p50_ms"] <= robot["delivery_p99_ms"]
            assert math.isfinite(robot["delivery_p99_ms"])
    for robot in report["phases"]["lockstep"]["robots"].values():
        assert 0 < robot["latency_p50_ms"] <= robot["latency_p99_ms"]


def test_period_jitter_is_the_distance_of_each_interval_from_the_period() -> None:
    """Exact oracle: stamps one period apart have no jitter; a publication 5 ms late shows
    as +5 ms on its interval and -5 ms on the next (both |.| = 5); fewer than 2 stamps give
    no interval."""
    period = 1_000_000_000 // 25  # 40 ms at 25 Hz, exact in ns
    on_time = np.arange(6, dtype=np.int64) * period
    assert period_jitter_ms(on_time, 25.0).tolist() == [0.0] * 5
    late = on_time.copy()
    late[3] += 5_000_000
    assert period_jitter_ms(late, 25.0).tolist() == [0.0, 0.0, 5.0, 5.0, 0.0]
    assert period_jitter_ms(on_time[:1], 25.0).size == 0
    assert period_jitter_ms([], 25.0).size == 0
