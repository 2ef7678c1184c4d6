"""``roger bench fleet`` end to end: a real daemon, real worker processes, real Zenoh."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from roger_daemon.bench.fleet import period_jitter_ms
from roger_daemon.bench.fleet_client import machine_window


def test_bench_fleet_runs_both_phases_against_a_real_daemon() -> None:
    """A short ``roger bench fleet`` (real daemon with two worker processes, real Zenoh on
    loopback): every robot is fed, learns and is answered, and every prediction it received
    decodes (they are validated after the phase, not in Zenoh's callback)."""
    out = subprocess.run(
        [sys.executable, "-m", "roger_daemon", "bench", "fleet", "--robots", "2",
         "--seconds", "1", "--warmup", "1", "--json"],
        capture_output=True, text=True, timeout=240, check=True)
    report = json.loads(out.stdout)
    for clock in ("realtime", "lockstep"):
        phase = report["phases"][clock]
        assert phase["exit_code"] == 0 and phase["decode_errors"] == 0
        assert phase["workers"] == "process"
        assert phase["predictions_received_by"] == (
            "feeding process" if clock == "lockstep" else "receiver process")
        assert set(phase["robots"]) == {"r0", "r1"}
        if phase["machine"]:  # /proc/stat readable: what else ran over the window
            assert set(phase["machine"]) == {"other_cpu_percent", "steal_percent"}
            assert math.isfinite(phase["machine"]["other_cpu_percent"])
            assert 0 <= phase["machine"]["steal_percent"] <= 100
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
    machines = [ph["machine"] for ph in report["phases"].values() if ph["machine"]]
    if machines:  # the summary carries the worst phase's, beside the verdict
        summary = report["summary"]
        assert summary["other_cpu_percent_max"] == max(m["other_cpu_percent"] for m in machines)
        assert summary["steal_percent_max"] == max(m["steal_percent"] for m in machines)


def test_index_predictions_counts_what_does_not_decode() -> None:
    """The one decoder of received predictions (the receiver process's and the feeding
    process's): each valid one lands under its robot with its tick and publish stamp on the
    monotonic clock; a bad payload or a robot not in the fleet is counted, not raised."""
    from protocols import Prediction, encode
    from protocols.aibo import DIMS
    from roger_daemon.bench.fleet_client import index_predictions

    pred = encode(Prediction("r0", 7, 0.2, mean=np.zeros(DIMS.y), var=np.ones(DIMS.y),
                             expert=-1, stamp_ns=5_000))
    stray = encode(Prediction("r9", 1, 0.0, mean=np.zeros(DIMS.y),
                              var=np.ones(DIMS.y), expert=-1))
    raw = [(100, "roger/r0/prediction", pred), (101, "roger/r1/prediction", b"\x00junk"),
           (102, "roger/r9/prediction", stray)]
    preds, errors = index_predictions(raw, ["r0", "r1"], 1_000)
    assert preds == {"r0": [(100, 7, 4_000)], "r1": []}
    assert errors == 2


def test_a_daemon_that_was_killed_fails_the_targets() -> None:
    """Figures within every target, but one phase's daemon had to be killed (exit -9, the
    harness's SIGKILL after 60 s): the run does not meet the targets, and says why."""
    from roger_daemon.bench.fleet import _summary

    robot = {"dropped": 0, "updates_per_s": 30.0, "predictions_per_s": 30.0,
             "jitter_p99_ms": 1.0, "latency_p99_ms": 5.0, "latency_p50_ms": 2.0}
    phases = {clock: {"robots": {"r0": robot}, "daemon_period_jitter_p99_ms": 0.5,
                      "exit_code": 0} for clock in ("realtime", "lockstep")}
    assert _summary(phases)["meets_targets"] is True
    phases["lockstep"]["exit_code"] = -9
    summary = _summary(phases)
    assert summary["meets_targets"] is False
    assert summary["daemon_exit_codes"] == {"realtime": 0, "lockstep": -9}


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


class _FakeClock:
    """``time.monotonic`` and ``time.sleep`` of a clock that moves only when slept on."""

    def __init__(self) -> None:
        self.now = 100.0

    def monotonic(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.now += seconds


class _Recorder:
    """The FleetClient calls ``feed`` makes, with the fake clock's time of each."""

    def __init__(self, robots: list[str], clock: _FakeClock) -> None:
        self.robots, self.clock = robots, clock
        self.sends: list[tuple[str, str, int, float]] = []

    def perception(self, robot: str, tick: int, x: np.ndarray) -> None:
        self.sends.append(("perception", robot, tick, self.clock.now))

    def action(self, robot: str, tick: int, y: np.ndarray, label: str) -> None:
        self.sends.append(("action", robot, tick, self.clock.now))


@pytest.mark.parametrize("stagger", [False, True])
def test_feed_sends_every_robot_at_the_tick_or_staggered_over_the_period(
        stagger: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    """Exact oracle on a fake clock (realtime feed, 4 robots at 25 Hz, 3 ticks): without
    ``--stagger`` every perception of tick t goes at t0 + t/25, the order rotating; with it
    robot i's goes i/4 of a period later, always in robot order."""
    import argparse

    from roger_daemon.bench import fleet_client
    from roger_daemon.bench.streams import FeedStream

    clock = _FakeClock()
    monkeypatch.setattr(fleet_client, "time", clock)
    robots = ["r0", "r1", "r2", "r3"]
    fleet = _Recorder(robots, clock)
    stream = FeedStream(x=np.zeros((8, 2)), y=np.zeros((8, 1)), labels=("a",) * 8)
    ticks = fleet_client.feed(fleet, stream, argparse.Namespace(rate=25.0),  # type: ignore[arg-type]
                              False, clock.now + 3 / 25 - 1e-9, stagger=stagger)
    assert ticks == 3
    perceptions = [(r, t, at) for kind, r, t, at in fleet.sends if kind == "perception"]
    assert len(perceptions) == 12 and len(fleet.sends) == 24  # an action with each
    for k, (robot, tick, at) in enumerate(perceptions):
        j = k % 4
        if stagger:
            assert robot == robots[j]
            assert at == pytest.approx(100.0 + tick / 25 + j / 100, abs=1e-12)
        else:
            assert robot == robots[(tick + j) % 4]
            assert at == pytest.approx(100.0 + tick / 25, abs=1e-12)


def test_a_receiver_that_cannot_start_is_an_error_not_a_hang(tmp_path: Path) -> None:
    """The realtime phase's receiver process (``bench/fleet_receiver.py``) given an endpoint
    Zenoh refuses exits before it is ready: ``start`` says so instead of waiting forever."""
    from roger_daemon.bench import fleet_receiver

    with pytest.raises(RuntimeError, match="fleet receiver was not ready within 60 s"):
        fleet_receiver.start("not-an-endpoint", tmp_path / "receipts.msgpack", timeout=60.0)
    assert not (tmp_path / "receipts.msgpack").exists()


def test_the_machine_window_is_empty_without_proc_stat_or_time() -> None:
    ticks = [100, 0, 50, 400, 0, 0, 0, 0]
    assert machine_window(None, ticks, ours_s=0.5, seconds=5.0) == {}
    assert machine_window(ticks, None, ours_s=0.5, seconds=5.0) == {}
    assert machine_window([0] * 8, ticks, ours_s=0.5, seconds=0.0) == {}
    # 1.5 CPU seconds busy, 0.5 of them ours, over 5 s: others used 20 % of one core
    assert machine_window([0] * 8, ticks, ours_s=0.5, seconds=5.0) == {
        "other_cpu_percent": 20.0, "steal_percent": 0.0}
