"""The live view: `roger view` serves a ROGER session on Foxglove's WebSocket protocol.

A real `roger view` subprocess subscribes over Zenoh (loopback, no multicast) to a publisher
in this test that plays simulator, controller and daemon; a real WebSocket client
(`websockets`) checks the advertised channels and schemas, subscribes, and decodes a few
messages: JSON plot channels with `json`, protobuf ones with the schema the server advertised.
Also: the offline conversion of a recorded session gives the same channels, and its scene
renders to a PNG.
"""

from __future__ import annotations

import base64
import json
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("foxglove")
websockets_sync = pytest.importorskip("websockets.sync.client")
pytest.importorskip("google.protobuf")

from protocols import Action, Command, EpisodeEvent, Perception, Prediction, Status, encode, keys  # noqa: E402
from protocols.aibo import ACTION_NAMES  # noqa: E402
from protocols.messages import ExpertOutput  # noqa: E402
from roger_daemon.config import ZenohSettings  # noqa: E402
from roger_daemon.harness import free_port  # noqa: E402
from roger_daemon.transport import open_session  # noqa: E402

pytestmark = pytest.mark.integration

EXPECTED = {
    "/scene": "foxglove.SceneUpdate", "/tf": "foxglove.FrameTransforms",
    "/camera/blobs": "foxglove.ImageAnnotations", "/camera/image": "foxglove.RawImage",
    "/roger/prediction": "roger.view.Prediction", "/roger/command": "roger.view.Command",
    "/roger/expert": "roger.view.Expert", "/roger/status": "foxglove.Log",
    "/roger/events": "foxglove.Log",
}
X = [0.2, -0.1, 0.3] + [0.0, 0.0, -1.0] * 5 + [0.0] * 5  # only the ball is seen
MEAN = [0.1 * (i + 1) for i in range(9)]


def messages(tick: int) -> list[tuple[str, bytes]]:
    expert = ExpertOutput(expert=2, p=1.0, mean=MEAN, var=[0.04] * 9, n=10, label="trap")
    start = [] if tick % 20 else [
        ("episode", encode(EpisodeEvent("aibo", tick, 0.0, event="start", episode=tick // 20,
                                        data={"location": 3})))]
    return [*start,
        ("episode", encode(EpisodeEvent("aibo", tick, tick / 30, event="truth", episode=0,
                                        data={"robot_x": 1.0, "robot_y": -0.5,
                                              "robot_yaw": 0.5, "ball_x": 1.5,
                                              "ball_y": 0.25}))),
        ("perception", encode(Perception("aibo", tick, tick / 30, x=X))),
        ("action", encode(Action("aibo", tick, tick / 30, y=MEAN, label="trap"))),
        ("prediction", encode(Prediction("aibo", tick, tick / 30, mean=MEAN, var=[0.04] * 9,
                                         expert=2, multimap=(expert,), latency_ms=1.5,
                                         mode="learn+predict", updates=tick))),
        ("command", encode(Command("aibo", tick, tick / 30, y=MEAN, source="hcc"))),
        ("status", encode(Status("aibo", tick, tick / 30, daemon="d1", mode="learn+predict",
                                 ticks=tick, updates=tick, updates_per_s=30.0, experts=1,
                                 queue_depth=0, dropped=3, info={
                                     "level": "WARN",
                                     "level_reasons": "3 pairs dropped (queue full)"}))),
    ]


@pytest.fixture
def publisher() -> Iterator[str]:
    ep = f"tcp/127.0.0.1:{free_port()}"
    session = open_session(ZenohSettings(listen=(ep,)))
    stop = threading.Event()

    def loop() -> None:
        tick = 0
        while not stop.is_set():
            for kind, payload in messages(tick):
                session.put(keys.key("aibo", kind), payload)
            tick += 1
            stop.wait(0.05)

    th = threading.Thread(target=loop, daemon=True)
    th.start()
    yield ep
    stop.set()
    th.join(10)
    session.close()


def _protobuf(schema_b64: str, name: str) -> Any:
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(schema_b64))
    pool = descriptor_pool.DescriptorPool()
    for fd in fds.file:
        pool.Add(fd)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(name))


def _advertised(ws: Any, deadline: float) -> dict[str, dict[str, Any]]:
    channels: dict[str, dict[str, Any]] = {}
    while set(EXPECTED) - set(channels) and time.monotonic() < deadline:
        try:
            raw = ws.recv(timeout=1.0)
        except TimeoutError:
            continue
        if isinstance(raw, str):
            op = json.loads(raw)
            if op.get("op") == "advertise":
                channels.update({c["topic"]: c for c in op["channels"]})
    return channels


def _first_messages(ws: Any, subs: dict[int, str], deadline: float) -> dict[str, bytes]:
    got: dict[str, bytes] = {}
    while set(subs.values()) - set(got) and time.monotonic() < deadline:
        try:
            raw = ws.recv(timeout=1.0)
        except TimeoutError:
            continue
        if isinstance(raw, bytes) and raw[0] == 0x01:  # MessageData
            (sub_id,) = struct.unpack_from("<I", raw, 1)
            got.setdefault(subs[sub_id], raw[13:])
    return got


def test_websocket_client_sees_the_channels_and_decodes_messages(publisher: str) -> None:
    port = free_port()
    view = subprocess.Popen([sys.executable, "-m", "roger_daemon", "view", "--port", str(port),
                             "--connect", publisher], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        assert view.stdout is not None
        while "roger view: ws://" not in (line := view.stdout.readline()):
            assert line, "roger view exited before serving"
        deadline = time.monotonic() + 60
        with websockets_sync.connect(f"ws://127.0.0.1:{port}",
                                     subprotocols=["foxglove.sdk.v1"]) as ws:
            channels = _advertised(ws, deadline)
            assert {t: channels[t]["schemaName"] for t in channels} == EXPECTED
            wanted = ["/roger/prediction", "/roger/status", "/scene"]
            subs = {i + 1: t for i, t in enumerate(wanted)}
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                {"id": i, "channelId": channels[t]["id"]} for i, t in subs.items()]}))
            got = _first_messages(ws, subs, deadline)
        assert set(got) == set(wanted)
        pred = json.loads(got["/roger/prediction"])
        assert list(pred["mean"]) == list(ACTION_NAMES)
        assert pred["mean"]["walk_forward"] == pytest.approx(MEAN[0])
        assert pred["std"]["action"] == pytest.approx(0.2) and pred["expert"] == 2
        ch = channels["/roger/status"]
        assert ch["encoding"] == "protobuf" and ch["schemaEncoding"] == "protobuf"
        status = _protobuf(ch["schema"], "foxglove.Log").FromString(got["/roger/status"])
        assert status.level == 3 and "3 pairs dropped" in status.message  # Warning
        assert status.name == "roger.daemon.d1"
        scene_cls = _protobuf(channels["/scene"]["schema"], "foxglove.SceneUpdate")
        scene = scene_cls.FromString(got["/scene"])
        ids = {e.id for e in scene.entities}
        assert ids <= {"field", "robot", "ball"} and ids
    finally:
        view.terminate()
        out, _ = view.communicate(timeout=30)
    assert view.returncode == 0, out
    assert "Traceback" not in out


def test_a_recorded_session_converts_to_the_same_channels_and_renders(tmp_path: Path) -> None:
    from mcap.writer import Writer

    from simulator.view.node import convert_log
    from simulator.view.render import read_messages, render_scene

    src = tmp_path / "session.mcap"
    with src.open("wb") as fh:
        w = Writer(fh)
        w.start()
        sid = w.register_schema("roger", "", b"")
        chans: dict[str, int] = {}
        for tick in range(40):
            for kind, payload in messages(tick):
                key = keys.key("aibo", kind)
                if key not in chans:
                    chans[key] = w.register_channel(key, "msgpack", sid)
                t = 1_000_000_000 + tick * 33_000_000
                w.add_message(chans[key], log_time=t, data=payload, publish_time=t)
        w.finish()
    out = tmp_path / "view.mcap"
    counts = convert_log(src, out)
    assert set(counts) == set(EXPECTED) and counts["/roger/prediction"] == 40
    decoded = read_messages(out, {"/roger/status", "/scene"})
    logs = [m for t, _, m in decoded if t == "/roger/status"]
    assert logs and logs[0]["level"] == "WARNING" and "daemon d1" in logs[0]["message"]
    png = tmp_path / "scene.png"
    drawn = render_scene(out, png)
    assert drawn == {"robot_poses": 40, "ball_positions": 40}
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
