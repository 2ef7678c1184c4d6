"""``roger bench worker``: one worker's handler serving several robots' models in turn."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from cli_testing import in_process

from roger_daemon.bench.streams import feed_stream
from roger_daemon.bench.worker import PARTS, _workers, serve_ticks


def test_serve_ticks_learns_and_answers_every_robot_each_tick() -> None:
    """Each tick every model learns one pair of its own slice and answers a prediction
    (the worker's handler, requests through msgpack as on the pipe)."""
    stream = feed_stream("aibo")
    workers = _workers(3, stream)
    times: dict[str, list[float]] = {part: [] for part in PARTS}
    serve_ticks(workers, stream, range(5), times)
    assert [w.rt.updates for w in workers] == [5, 5, 5]
    assert all(len(v) == 15 and min(v) > 0 for v in times.values())
    # each robot learned its own slice of the stream: the models answer differently
    means = [w.rt.model.predict_one(stream.x[0]).mean for w in workers]
    assert not np.array_equal(means[0], means[1]) and not np.array_equal(means[1], means[2])


def test_bench_worker_reports_cpu_per_robot_tick_as_json() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "roger_daemon", "bench", "worker", "--robots", "2",
         "--seconds", "0.5", "--warmup", "20", "--rate", "0", "--json"],
        capture_output=True, text=True, timeout=240, check=True)
    report = json.loads(out.stdout)
    assert report["robot_ticks"] > 0 and report["robot_ticks"] % 2 == 0
    assert report["cpu_ms_per_robot_tick"] > 0 and len(report["experts"]) == 2
    for part in PARTS:
        assert 0 < report[f"{part}_p50_ms"] <= report[f"{part}_p99_ms"]
    assert report["settings"]["robots"] == 2 and "speed_probe" in report["machine"]


@pytest.mark.parametrize("args, message", [
    (["--robots", "0"], "--robots must be an integer >= 1, got 0"),
    (["--rate", "-1"], "--rate must be a number >= 0 (0: back to back), got -1.0"),
    (["--seconds", "0"], "--duration must be a number > 0, got 0.0"),  # the old spelling
])
def test_bench_worker_refuses_bad_arguments(args: list[str], message: str,
                                            capsys: pytest.CaptureFixture[str],
                                            monkeypatch: pytest.MonkeyPatch) -> None:
    """In this process (tests/cli_testing.py: a traceback fails the test here)."""
    with in_process(capsys, monkeypatch) as run:
        out = run("bench", "worker", *args)
    assert out.returncode == 2 and message in out.stderr
