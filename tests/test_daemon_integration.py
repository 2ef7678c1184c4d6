"""The daemon as a real subprocess, real Zenoh on 127.0.0.1 (a free port per test, no multicast)."""

from __future__ import annotations

import math
import os
import signal
import socket
import time
from collections.abc import Iterator
from pathlib import Path

import msgpack
import numpy as np
import pytest

from protocols import Perception, encode
from protocols.messages import MAX_PAYLOAD_BYTES
from roger_daemon.daemon.checkpoint import list_checkpoints, read_checkpoint
from roger_daemon.harness import Client, DaemonProcess, free_port, write_config
from roger_daemon.learner.synthetic import subtask_stream

pytestmark = pytest.mark.integration

LABELS = ("seek", "trap", "aim", "kick")
STREAM = subtask_stream(400)


def header(**over: object) -> dict[str, object]:
    m: dict[str, object] = {"v": 1, "robot": "aibo", "tick": 1, "t": 0.0, "stamp_ns": 1}
    m.update(over)
    return m


@pytest.fixture
def procs() -> Iterator[list[DaemonProcess]]:
    started: list[DaemonProcess] = []
    yield started
    for p in started:
        p.kill()


def start(procs: list[DaemonProcess], cfg: Path, *args: str,
          env: dict[str, str] | None = None) -> DaemonProcess:
    d = DaemonProcess(cfg, args=args, env=env)
    procs.append(d)
    d.wait_ready()
    return d


def feed_lockstep(client: Client, ticks: range) -> None:
    for t in ticks:
        client.perception(t, STREAM.x[t])
        client.wait_prediction(t)
        client.action(t, STREAM.y[t], LABELS[STREAM.labels[t]])


def test_realtime_predictions_at_30_hz_while_learning(
    tmp_path: Path, procs: list[DaemonProcess]
) -> None:
    port = free_port()
    cfg = write_config(tmp_path / "d.toml", port=port, workdir=tmp_path,
                       daemon={"clock": "realtime", "rate_hz": 30.0})
    start(procs, cfg)
    client = Client(f"tcp/127.0.0.1:{port}")
    try:
        client.wait_daemon()
        period = 1 / 30
        t_begin = time.monotonic()
        tick = 0
        while True:
            now = time.monotonic()
            if now - t_begin >= 3.5:  # 1 s to settle, a 2 s window, 0.5 s of margin
                break
            client.perception(tick, STREAM.x[tick])
            client.action(tick, STREAM.y[tick], LABELS[STREAM.labels[tick]])
            tick += 1
            time.sleep(max(0.0, t_begin + tick * period - time.monotonic()))
        w0 = int((t_begin + 1.0) * 1e9)
        w1 = w0 + 2_000_000_000
        in_window = [r.msg for r in client.predictions if w0 <= r.recv_ns < w1]
        rate = len(in_window) / 2.0
        st = client.wait_status()
        # never faster than its 30 Hz timer; how close to 30 Hz it stays on a loaded machine is
        # measured by `roger bench daemon` (jitter), not asserted here
        assert 10.0 <= rate <= 31.5, f"{rate} Hz over 2 s; daemon status info {st.info}"
        for p in in_window:
            assert np.all(np.isfinite(p.mean)) and np.all(p.var > 0)
            assert math.isfinite(p.latency_ms) and p.latency_ms >= 0
            assert p.mode == "learn+predict"
        assert in_window[-1].updates > in_window[0].updates  # it learned meanwhile
        assert st.updates > 0 and st.invalid == {} and st.info["clock"] == "realtime"
        assert client.errors == []
    finally:
        client.close()


def test_bad_input_is_counted_and_leaves_the_model_unchanged(
    tmp_path: Path, procs: list[DaemonProcess]
) -> None:
    port = free_port()
    cfg = write_config(tmp_path / "d.toml", port=port, workdir=tmp_path)
    d = start(procs, cfg)
    client = Client(f"tcp/127.0.0.1:{port}")
    try:
        client.wait_daemon()
        feed_lockstep(client, range(12))
        client.wait_status(lambda s: s.updates == 12 and s.queue_depth == 0)
        client.control("checkpoint")
        before = client.wait_status(lambda s: s.info["checkpoints_written"] == 1)
        bad: list[tuple[str, bytes, str]] = [
            ("perception", b"\xc1\x00garbage", "not_msgpack"),
            ("action", msgpack.packb(["not", "a", "map"]), "not_a_map"),
            ("perception", msgpack.packb({"hello": "world"}), "bad_version"),
            ("perception", msgpack.packb(header()), "missing_field"),
            ("perception", msgpack.packb(header(x=[0.0] * 22)), "wrong_dimension"),
            ("action", msgpack.packb(header(y=[0.0] * 10, label="seek")), "wrong_dimension"),
            ("perception", msgpack.packb(header(x=[math.nan] * 23)), "not_finite"),
            ("action", msgpack.packb(header(y=[math.inf] + [0.0] * 8, label="x")), "not_finite"),
            ("perception", msgpack.packb(header(x="23 floats")), "wrong_type"),
            ("action", msgpack.packb(header(tick=2.5, y=[0.0] * 9, label="")), "wrong_type"),
            ("perception", b"\x00" * (MAX_PAYLOAD_BYTES + 4096), "oversized"),
            ("perception", msgpack.packb(header(robot="ghost", x=[0.0] * 23)), "unknown_robot"),
            ("control", msgpack.packb(header(op="mode", mode="fly")), "bad_value"),
        ]
        expected: dict[str, int] = {}
        for kind, payload, reason in bad:
            client.put(kind, payload)
            expected[reason] = expected.get(reason, 0) + 1
        # a robot this daemon does not serve
        client.put("perception", encode(Perception("ghost", 1, 0.0, x=STREAM.x[0])),
                   robot="ghost")
        expected["unknown_robot"] += 1
        time.sleep(0.3)
        client.control("checkpoint")
        after = client.wait_status(lambda s: s.info["checkpoints_written"] == 2)
        assert after.invalid == expected
        assert after.updates == before.updates == 12 and after.ticks == before.ticks
        assert after.info["checkpoint_digest"] == before.info["checkpoint_digest"]
        first, second = sorted(list_checkpoints(tmp_path / "checkpoints", "aibo"))
        a, b = read_checkpoint(first), read_checkpoint(second)
        assert set(a.model) == set(b.model)
        for k in a.model:
            np.testing.assert_array_equal(a.model[k], b.model[k])
        # still alive and serving
        client.perception(12, STREAM.x[12])
        assert client.wait_prediction(12).updates == 12
        assert d.proc.poll() is None
        assert "rejected message" in d.log()
    finally:
        client.close()


def test_a_daemon_that_does_not_stop_in_time_is_killed_not_left_behind(
    tmp_path: Path, procs: list[DaemonProcess]
) -> None:
    """``DaemonProcess.terminate`` kills a daemon that has not exited ``timeout`` seconds after
    SIGTERM (here: stopped by SIGSTOP, so the SIGTERM stays pending) and reports exit code -9;
    the benchmarks record that instead of stopping with the daemon still running."""
    cfg = write_config(tmp_path / "d.toml", port=free_port(), workdir=tmp_path)
    d = start(procs, cfg)
    os.kill(d.proc.pid, signal.SIGSTOP)
    code, _ = d.terminate(timeout=1.0)
    assert code == -signal.SIGKILL and d.proc.poll() == -signal.SIGKILL


def test_sigterm_checkpoints_and_restart_resumes_identical_model(
    tmp_path: Path, procs: list[DaemonProcess]
) -> None:
    port = free_port()
    cfg = write_config(tmp_path / "d.toml", port=port, workdir=tmp_path)
    d = start(procs, cfg)
    client = Client(f"tcp/127.0.0.1:{port}")
    try:
        client.wait_daemon()
        feed_lockstep(client, range(25))
        client.wait_status(lambda s: s.updates == 25 and s.queue_depth == 0)
    finally:
        client.close()
    code, seconds = d.terminate(60.0)  # a generous deadline: killed (-9) if it hangs
    assert code == 0, (code, seconds, d.log())
    files = list_checkpoints(tmp_path / "checkpoints", "aibo")
    assert len(files) == 1
    saved = read_checkpoint(files[0])
    assert saved.meta.updates == 25 and saved.meta.reason == "shutdown"
    assert "checkpoint" in d.log() and "written" in d.log()

    # a corrupt newer checkpoint is reported and skipped
    bogus = files[0].with_name("ckpt-00000042.npz")
    bogus.write_bytes(files[0].read_bytes()[:1000])
    port2 = free_port()
    cfg2 = write_config(tmp_path / "d2.toml", port=port2, workdir=tmp_path)
    d2 = start(procs, cfg2)
    assert f"skipping corrupt or unusable checkpoint {bogus}" in d2.log()
    client = Client(f"tcp/127.0.0.1:{port2}")
    try:
        client.wait_daemon()
        client.control("checkpoint")
        st = client.wait_status(lambda s: s.info["checkpoints_written"] == 1)
        assert st.info["resumed_from"] == str(files[0])
        assert st.updates == 25 and st.ticks == 25
        assert st.info["checkpoint_digest"] == saved.meta.model_digest
        # it continues: the next perception is answered by the resumed model
        client.perception(25, STREAM.x[25])
        assert client.wait_prediction(25).updates == 25
    finally:
        client.close()
    code, _ = d2.terminate()
    assert code == 0
    resumed = read_checkpoint(list_checkpoints(tmp_path / "checkpoints", "aibo")[0])
    assert set(resumed.model) == set(saved.model)
    for k in saved.model:
        np.testing.assert_array_equal(resumed.model[k], saved.model[k])

    # --fresh ignores every checkpoint
    port3 = free_port()
    d3 = start(procs, write_config(tmp_path / "d3.toml", port=port3, workdir=tmp_path),
               "--fresh")
    client = Client(f"tcp/127.0.0.1:{port3}")
    try:
        client.wait_daemon()
        st = client.wait_status()
        assert st.updates == 0 and st.info["resumed_from"] == ""
    finally:
        client.close()
    assert d3.terminate()[0] == 0


def test_systemd_notify_protocol(tmp_path: Path, procs: list[DaemonProcess]) -> None:
    sock_path = tmp_path / "notify.sock"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(sock_path))
    sock.settimeout(10.0)
    try:
        port = free_port()
        cfg = write_config(tmp_path / "d.toml", port=port, workdir=tmp_path)
        env = {"NOTIFY_SOCKET": str(sock_path), "WATCHDOG_USEC": "400000"}
        d = start(procs, cfg, env=env)
        got: list[str] = []

        def receive_until(field: str) -> None:
            while not any(field in m for m in got):
                got.append(sock.recv(4096).decode())

        receive_until("READY=1")
        ready = next(m for m in got if "READY=1" in m)
        assert "STATUS=serving aibo" in ready
        # while the models load (on a cold numba cache: compiling the kernels) it asks
        # systemd for more start-up time, and no longer once it is ready
        extended = [i for i, m in enumerate(got) if m.startswith("EXTEND_TIMEOUT_USEC=")]
        assert extended and extended[-1] < got.index(ready)
        assert got[0].startswith("STATUS=starting: loading the models")
        receive_until("WATCHDOG=1")
        n_before = sum("WATCHDOG=1" in m for m in got)
        receive_until("STATUS=aibo: learn+predict")  # the 1 Hz status line
        assert sum("WATCHDOG=1" in m for m in got) > n_before  # it keeps pinging
        code, _ = d.terminate(sig=signal.SIGINT)  # Ctrl-C shuts down as cleanly as SIGTERM
        assert code == 0
        receive_until("STOPPING=1")
        assert "received SIGINT" in d.log()
        assert os.getpid() != d.proc.pid
    finally:
        sock.close()


def test_bad_config_stops_startup_naming_the_key(tmp_path: Path) -> None:
    cfg = tmp_path / "bad.toml"
    cfg.write_text('[daemon]\nrate_hz = "fast"\n', encoding="utf-8")
    d = DaemonProcess(cfg)
    code = d.proc.wait(30)
    d.kill()
    assert code == 2
    assert 'config error: daemon.rate_hz must be a number > 0, got "fast"' in d.log()
