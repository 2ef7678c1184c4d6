"""The 21 rough edges of issue 56, one test (or more) each; every one failed before its fix.

Items 14 (the README's learner snippet) and 15 (no msgpack decoder) are
``tests/test_examples.py`` and ``tests/test_log_decoding.py``; 21 (the recording size) is in
``tests/test_log_decoding.py`` too; the naming conventions are ``tests/test_cli_conventions.py``.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
import tomllib
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
from cli_testing import Ran, in_process

from protocols import EpisodeEvent, Perception, encode, keys
from roger_daemon.cli import build_parser
from roger_daemon.cli import main as roger
from roger_daemon.config import ZenohSettings, parse_config
from roger_daemon.harness import free_port, interruptible_child
from roger_daemon.recording import SessionRecorder, session_metadata
from roger_daemon.zenoh_session import open_session

ROOT = Path(__file__).resolve().parents[1]
ROGER = [sys.executable, "-m", "roger_daemon"]
SESSION = ROOT / "tests" / "data" / "sessions" / "sim-loc7-seed0.mcap"


def run(*argv: str, timeout: float = 120, cwd: Path | None = None
        ) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*ROGER, *argv], capture_output=True, text=True, timeout=timeout,
                          cwd=cwd)


@pytest.fixture
def here(capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
         ) -> Iterator[Callable[..., Ran]]:
    """``roger ARGV`` in this process (tests/cli_testing.py): for the commands that only read
    and write files; those that serve, listen or take signals run as processes (:func:`run`)."""
    with in_process(capsys, monkeypatch) as run:
        yield run


@pytest.fixture
def publisher() -> Iterator[str]:
    """A peer on loopback publishing perceptions of robots "lonely" and "other" at ~50 Hz."""
    ep = f"tcp/127.0.0.1:{free_port()}"
    session = open_session(ZenohSettings(listen=(ep,)))
    stop = threading.Event()

    def loop() -> None:
        tick = 0
        while not stop.is_set():
            for robot in ("lonely", "other"):
                session.put(keys.perception(robot),
                            encode(Perception(robot, tick, tick / 30, x=np.zeros(3))))
            tick += 1
            time.sleep(0.02)

    th = threading.Thread(target=loop, daemon=True)
    th.start()
    try:
        yield ep
    finally:
        stop.set()
        th.join(10)
        session.close()


# 1 -------------------------------------------------------------------------------------------

def test_01_hz_gives_up_after_its_timeout_and_says_so_in_json() -> None:
    out = run("hz", "aibo/status", "--connect", f"tcp/127.0.0.1:{free_port()}", "--timeout",
              "1", "--json", timeout=60)
    assert out.returncode == 1, out.stderr
    assert json.loads(out.stdout.splitlines()[-1]) == {
        "key": "roger/aibo/status", "messages": 0, "rate_hz": None,
        "error": "no messages within 1 s"}
    assert "no messages on roger/aibo/status within 1 s" in out.stderr


# 2, 3, 4, 5, 18: roger view -------------------------------------------------------------------

foxglove = pytest.importorskip("foxglove")


@pytest.mark.integration
def test_02_view_warns_when_nothing_arrives_within_its_timeout() -> None:
    out = run("view", "--port", "0", "--connect", f"tcp/127.0.0.1:{free_port()}",
              "--timeout", "1", "--duration", "3", timeout=60)
    assert out.returncode == 0, out.stderr
    assert "nothing received on roger/aibo/* within 1 s" in out.stderr


def test_03_view_of_a_file_that_is_not_mcap_is_refused_leaving_nothing(
        tmp_path: Path, here: Callable[..., Ran]) -> None:
    notes = tmp_path / "notes.mcap"
    notes.write_text("not a log\n")
    for argv in (["view", str(notes)], ["view", "--log", str(notes)]):
        out = here(*argv)
        assert out.returncode == 2 and "Traceback" not in out.stderr
        assert "is not an MCAP file" in out.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.mcap"]  # nothing left


def _small_log(directory: Path) -> Path:
    rec = SessionRecorder(directory, robot="aibo", metadata=session_metadata(robot="aibo"))
    for tick in range(40):
        if tick % 20 == 0:
            rec.write(keys.episode("aibo"), encode(EpisodeEvent(
                "aibo", tick, 0.0, event="start", episode=tick // 20)),
                log_time_ns=tick + 1, publish_time_ns=tick + 1, sequence=tick)
        x0 = -2.0 if tick < 20 else 2.0  # the second episode starts at the other end
        rec.write(keys.episode("aibo"), encode(EpisodeEvent(
            "aibo", tick, tick / 30, event="truth", episode=tick // 20,
            data={"robot_x": x0 + 0.01 * tick, "robot_y": 0.0, "robot_yaw": 0.0,
                  "ball_x": 0.0, "ball_y": 0.0})),
            log_time_ns=tick + 2, publish_time_ns=tick + 2, sequence=tick)
    rec.close()
    return rec.path


def test_04_05_18_view_converts_a_positional_log_keeps_metadata_and_overwrites_nothing(
        tmp_path: Path, here: Callable[..., Ran]) -> None:
    from mcap.reader import make_reader

    log = _small_log(tmp_path / "logs")
    out_dir = tmp_path / "views"
    done = here("view", str(log), "--out", str(out_dir))  # 5: positional
    assert done.returncode == 0, done.stderr
    out = out_dir / f"{log.stem}.foxglove.mcap"
    with out.open("rb") as f:  # 18: the session metadata is kept
        meta = {m.name: dict(m.metadata) for m in make_reader(f).iter_metadata()}
    assert meta["roger.session"]["robot"] == "aibo"
    assert meta["roger.session"]["session_id"] == log.stem
    before = out.read_bytes()
    again = here("view", str(log), "--out", str(out_dir))  # 4: no --force
    assert again.returncode == 2 and "exists; pass --force" in again.stderr
    assert out.read_bytes() == before
    assert here("view", str(log), "--out", str(out_dir), "--force").returncode == 0


# 6 -------------------------------------------------------------------------------------------

@pytest.mark.integration
def test_06_the_view_serves_foxglove_sdk_v1_and_refuses_websocket_v1_as_documented() -> None:
    ws_client = pytest.importorskip("websockets.sync.client")
    from websockets.exceptions import InvalidStatus

    from simulator.view.node import SUBPROTOCOL

    doc = (ROOT / "docs" / "live-view.md").read_text()
    assert SUBPROTOCOL == "foxglove.sdk.v1" and SUBPROTOCOL in doc
    assert "foxglove.websocket.v1" in doc and "HTTP 400" in doc
    port = free_port()
    view = subprocess.Popen([*ROGER, "view", "--port", str(port), "--connect",
                             f"tcp/127.0.0.1:{free_port()}", "--duration", "60"],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        assert view.stdout is not None
        while "roger view: ws://" not in (line := view.stdout.readline()):
            assert line, "roger view exited before serving"
        with pytest.raises(InvalidStatus) as refused:
            with ws_client.connect(f"ws://127.0.0.1:{port}",
                                   subprotocols=["foxglove.websocket.v1"]):
                pass
        assert refused.value.response.status_code == 400
        with ws_client.connect(f"ws://127.0.0.1:{port}", subprotocols=[SUBPROTOCOL]) as ws:
            assert ws.subprotocol == SUBPROTOCOL
    finally:
        view.terminate()
        view.wait(30)


# 7 -------------------------------------------------------------------------------------------

def test_07_the_daemon_reports_absolute_paths(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    cfg = parse_config({"checkpoint": {"dir": "ck"}, "recording": {"dir": "rec"}})
    assert cfg.checkpoint.dir == tmp_path / "ck" and cfg.recording.dir == tmp_path / "rec"
    assert parse_config({}).checkpoint.dir.is_absolute()


# 8, 9 ----------------------------------------------------------------------------------------

def test_08_export_to_dash_is_refused_and_writes_no_file_named_dash(
        tmp_path: Path, here: Callable[..., Ran]) -> None:
    out = here("log", "export", str(SESSION), "--out", "-", cwd=tmp_path)
    assert out.returncode == 2 and "--out must be a directory, got '-'" in out.stderr
    assert list(tmp_path.iterdir()) == []


def test_09_exported_files_get_the_mode_open_would_give(tmp_path: Path) -> None:
    umask = os.umask(0o022)
    os.umask(umask)
    assert roger(["log", "export", str(SESSION), "--out", str(tmp_path)]) == 0
    (out,) = tmp_path.glob("*.json.mcap")
    assert out.stat().st_mode & 0o777 == 0o666 & ~umask != 0o600


# 10 ------------------------------------------------------------------------------------------

@pytest.mark.integration
def test_10_record_interrupted_by_ctrl_c_exits_130_like_every_command(tmp_path: Path) -> None:
    with interruptible_child():
        proc = subprocess.Popen([*ROGER, "record", "--out", str(tmp_path), "--listen",
                                 f"tcp/127.0.0.1:{free_port()}", "--connect-timeout", "0"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        assert "recording" in proc.stdout.readline()
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, err
    assert "Traceback" not in err and list(tmp_path.glob("*.mcap"))


@pytest.mark.integration
@pytest.mark.parametrize(("sig", "status"), [(signal.SIGINT, 130), (signal.SIGTERM, 0)])
def test_10_view_exits_130_after_ctrl_c_and_0_when_its_supervisor_stops_it(
        sig: signal.Signals, status: int) -> None:
    """docs/cli.md, exit statuses: Ctrl-C 130 as every command; SIGTERM (roger up's stop) 0."""
    pytest.importorskip("foxglove")
    with interruptible_child():
        proc = subprocess.Popen([*ROGER, "view", "--port", "0", "--connect",
                                 f"tcp/127.0.0.1:{free_port()}", "--duration", "120"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        assert "roger view: ws://" in proc.stdout.readline()  # serving: inside its loop
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == status, err
    assert "Traceback" not in err


# 11, 12 --------------------------------------------------------------------------------------

@pytest.mark.integration
def test_11_hz_on_a_pattern_reports_each_key(publisher: str) -> None:
    out = run("hz", "roger/*/perception", "--connect", publisher, "--json", "--duration",
              "2.5", "--timeout", "20", timeout=60)
    assert out.returncode == 0, out.stderr
    reports = [json.loads(line) for line in out.stdout.splitlines()]
    keys_seen = {r["key"] for r in reports if r.get("messages")}
    assert {"roger/lonely/perception", "roger/other/perception",
            "roger/*/perception"} <= keys_seen
    last = {r["key"]: r for r in reports}
    assert last["roger/*/perception"]["messages"] == (
        last["roger/lonely/perception"]["messages"] + last["roger/other/perception"]["messages"])


@pytest.mark.integration
def test_12_list_shows_the_robots_no_daemon_serves(publisher: str) -> None:
    out = run("list", "--connect", publisher, "--json", "--wait", "1.0", "--timeout", "1",
              timeout=60)
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout) == {"daemons": [], "unserved": ["lonely", "other"]}


# 13 ------------------------------------------------------------------------------------------

def test_13_no_pybullet_banner_on_stderr() -> None:
    out = subprocess.run([sys.executable, "-c", "import simulator.world"], capture_output=True,
                         text=True, timeout=120, cwd=ROOT)
    assert out.returncode == 0 and "pybullet build time" not in out.stderr + out.stdout


# 16 ------------------------------------------------------------------------------------------

def test_16_the_scene_render_draws_one_path_per_episode(tmp_path: Path) -> None:
    pytest.importorskip("google.protobuf")
    from simulator.view.node import convert_log
    from simulator.view.render import episode_paths, render_scene

    log = _small_log(tmp_path / "logs")
    view = tmp_path / "view.mcap"
    convert_log(log, view)
    assert render_scene(view, tmp_path / "scene.png")["robot_poses"] == 40
    paths = episode_paths(view)["robot"]
    assert [len(p) for p in paths] == [20, 20]  # not one line from x = -1.8 back to 2.0
    assert paths[0][-1][0] == pytest.approx(-1.81) and paths[1][0][0] == pytest.approx(2.2)


# 17 ------------------------------------------------------------------------------------------

def test_17_demo_and_up_take_their_ports(capsys: pytest.CaptureFixture[str]) -> None:
    parser = build_parser(__import__("roger_daemon.cli").cli.COMMANDS, "roger", "demo")
    args = parser.parse_args(["demo", "--daemon-port", "7600", "--sim-port", "7601"])
    assert (args.daemon_port, args.sim_port) == (7600, 7601)
    assert roger(["up", str(ROOT / "configs" / "up-demonstration.toml"), "--daemon-port",
                  "7600", "--sim-port", "7601", "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "--listen tcp/127.0.0.1:7601" in out and 'zenoh.listen=["tcp/127.0.0.1:7600"]' in out
    assert "7447" not in out and "7450" not in out


# 19 ------------------------------------------------------------------------------------------

@pytest.mark.parametrize(("name", "path"), [
    ("secure-router", "zenoh/secure/router.json5"), ("secure-daemon", "zenoh/secure/daemon.json5"),
    ("secure-daemon-toml", "zenoh/secure/daemon.toml"),
    ("secure-robot", "zenoh/secure/robot.json5"),
    ("secure-operator", "zenoh/secure/operator.json5"),
    ("secure-credentials", "zenoh/secure/credentials.example.txt"),
    ("held-out-poses", "held-out-poses.toml"), ("robot-aibo", "robots/aibo.toml"),
])
def test_19_config_example_prints_every_file_the_readme_uses(
        name: str, path: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert roger(["config", "example", name]) == 0
    assert capsys.readouterr().out == (ROOT / "configs" / path).read_text(encoding="utf-8")


def test_19_the_wheel_carries_those_files() -> None:
    data = tomllib.loads((ROOT / "pyproject.toml").read_text())
    shipped = data["tool"]["setuptools"]["package-data"]["roger_daemon"]
    assert {"configs/robots/*.toml", "configs/zenoh/secure/*"} <= set(shipped)


# 20 ------------------------------------------------------------------------------------------

def test_20_the_licence_is_an_spdx_expression_for_current_setuptools() -> None:
    """setuptools 77 deprecates ``license = {text = ...}`` (a warning on every build)."""
    data = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert data["project"]["license"] == "MIT"
    assert data["project"]["license-files"] == ["LICENSE"]
    assert "setuptools>=77" in data["build-system"]["requires"]
    assert "build/" in (ROOT / ".gitignore").read_text().split()
    assert "python -m build" in (ROOT / "docs" / "cli.md").read_text()
