"""Replay against the real daemon: record a lockstep session with `roger daemon`, replay it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from daemon_sessions import as_version_1, synthetic_stream

from protocols.messages import Dims
from roger_daemon.recording import is_complete, list_session_files
from roger_daemon.replay import replay_session
from roger_daemon.replay.compare import REL_TOL

harness = pytest.importorskip("roger_daemon.harness")

pytestmark = pytest.mark.integration


def test_replay_reproduces_a_real_daemon_session(tmp_path: Path) -> None:
    port = harness.free_port()
    cfg = harness.write_config(
        tmp_path / "daemon.toml", port=port, workdir=tmp_path,
        recording={"enabled": True}, daemon={"clock": "lockstep", "seed": 5},
        robots=[{"id": "sim", "x_dim": 1, "y_dim": 1}],
    )
    daemon = harness.DaemonProcess(cfg)
    try:
        daemon.wait_ready()
        client = harness.Client(f"tcp/127.0.0.1:{port}", robot="sim", dims=Dims(1, 1))
        try:
            client.wait_daemon()
            x, y, labels = synthetic_stream("sqrt", 160)
            for t in range(160):
                if t == 50:
                    client.control("mode", "predict")
                if t == 70:
                    client.control("mode", "learn+predict")
                if t == 120:
                    client.control("reset")
                client.perception(t, x[t])
                if t != 33:
                    client.action(t, y[t], labels[t])
                client.wait_prediction(t)
        finally:
            client.close()
        code, _ = daemon.terminate()
        assert code == 0
    finally:
        daemon.kill()
    files = list_session_files(tmp_path / "recordings", robot="sim")
    assert len(files) == 1 and is_complete(files[0].path)
    res = replay_session(files[0].path)
    assert res.ok(REL_TOL), res.summary(REL_TOL)
    assert len(res.diffs) == 160 and len(res.timeline.segments) == 2
    assert res.seed == 5 and res.n_learned == 40  # ticks 120..159 after the reset
    assert res.timeline.decisions and res.digests and res.bit_identical()  # final checkpoint
    np.testing.assert_array_equal([p.tick for p in res.pairs], list(range(120, 160)))
    # the daemon learned nothing in mode predict (ticks 50-69): its decisions say so, and the
    # log read as an older daemon's (re-pairing its inputs) agrees
    first = [p.tick for p in res.timeline.segments[0].pairs]
    assert first == [t for t in range(120) if t != 33 and not 50 <= t < 70]
    old = replay_session(as_version_1(files[0].path, tmp_path / "v1.mcap"))
    assert old.ok(REL_TOL) and [p.tick for p in old.timeline.segments[0].pairs] == first
    assert old.timeline.ignored_not_learning == 2 * 20  # ticks 50-69 in mode predict
