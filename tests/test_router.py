"""``roger router``: daemon and client as Zenoh clients of a router; the ACL example config."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from protocols import keys
from roger_daemon.harness import Client, DaemonProcess, free_port, write_config
from roger_daemon.learner.synthetic import subtask_stream

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[1]
STREAM = subtask_stream(10)


class Router:
    def __init__(self, config: Path, port: int, log: Path) -> None:
        self.port = port
        self.log_path = log
        self._log = open(log, "ab")  # closed in stop()
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "roger_daemon", "router", "--config", str(config),
             "--listen", f"tcp/127.0.0.1:{port}"],
            stdout=self._log, stderr=subprocess.STDOUT, cwd=ROOT,
            env={**os.environ, "RUST_LOG": "error"},
        )
        end = time.monotonic() + 120
        while "listening on" not in log.read_text():
            if self.proc.poll() is not None or time.monotonic() > end:
                raise RuntimeError(f"router did not start:\n{log.read_text()}")
            time.sleep(0.05)

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        code = self.proc.wait(10)
        self._log.close()
        return code


@pytest.fixture
def router_factory(tmp_path: Path) -> Iterator[list[Router]]:
    started: list[Router] = []
    yield started
    for r in started:
        if r.proc.poll() is None:
            r.proc.kill()
            r.proc.wait(10)


def _through_router(tmp_path: Path, router_cfg: str, routers: list[Router]) -> None:
    port = free_port()
    router = Router(ROOT / "configs/zenoh" / router_cfg, port, tmp_path / "router.log")
    routers.append(router)
    endpoint = f"tcp/127.0.0.1:{port}"
    cfg = write_config(
        tmp_path / "d.toml", port=port, workdir=tmp_path,
        zenoh={"mode": "client", "connect": [endpoint]},
    )
    # client mode: no listen key at all (write_config's listen is replaced)
    text = cfg.read_text().replace(f'listen = ["{endpoint}"]\n', "")
    cfg.write_text(text)
    daemon = DaemonProcess(cfg)
    try:
        daemon.wait_ready()
        client = Client(endpoint, mode="client")
        try:
            client.wait_daemon()
            for t in range(5):
                client.perception(t, STREAM.x[t])
                pred = client.wait_prediction(t)
                assert pred.updates == t
                client.action(t, STREAM.y[t], "seek")
            st = client.wait_status(lambda s: s.updates == 5)
            assert st.invalid == {}
        finally:
            client.close()
        assert daemon.terminate()[0] == 0
    finally:
        daemon.kill()
    assert router.stop() == 0


def test_daemon_and_client_exchange_through_roger_router(
    tmp_path: Path, router_factory: list[Router]
) -> None:
    _through_router(tmp_path, "router.json5", router_factory)


def test_acl_router_passes_roger_traffic(tmp_path: Path, router_factory: list[Router]) -> None:
    _through_router(tmp_path, "router-acl.json5", router_factory)
    assert "access control on" in (tmp_path / "router.log").read_text()


def test_acl_router_blocks_other_keys(tmp_path: Path, router_factory: list[Router]) -> None:
    import zenoh

    port = free_port()
    router = Router(ROOT / "configs/zenoh/router-acl.json5", port, tmp_path / "router.log")
    router_factory.append(router)

    def client() -> zenoh.Session:
        cfg = zenoh.Config()
        cfg.insert_json5("mode", '"client"')
        cfg.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
        cfg.insert_json5("scouting/multicast/enabled", "false")
        return zenoh.open(cfg)

    got: list[str] = []
    a, b = client(), client()
    try:
        b.declare_subscriber("roger/**", lambda s: got.append(str(s.key_expr)))
        b.declare_subscriber("other/**", lambda s: got.append(str(s.key_expr)))
        time.sleep(0.5)
        for key in (keys.perception("aibo"), "roger/aibo/evil", "other/thing",
                    keys.command("aibo")):
            a.put(key, b"payload", congestion_control=zenoh.CongestionControl.BLOCK)
        end = time.monotonic() + 20
        while len(got) < 2 and time.monotonic() < end:
            time.sleep(0.05)
        time.sleep(0.3)
    finally:
        a.close()
        b.close()
    assert sorted(got) == sorted([keys.perception("aibo"), keys.command("aibo")])
    assert router.stop() == 0
