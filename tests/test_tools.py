"""The operator tools (roger list/status/echo/hz/control) against a real daemon on loopback.

One daemon subprocess (lockstep, realtime off the table, multicast scouting off, a free port)
serves the whole module; each tool runs in-process through ``roger_daemon.cli.main`` with its
output captured. Deadlines are generous; nothing asserts on wall-clock durations.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from protocols import Status, encode, keys
from roger_daemon.cli import main
from roger_daemon.client import RobotClient, checkpoint_outcome
from roger_daemon.harness import (
    Client,
    DaemonProcess,
    free_port,
    interruptible_child,
    write_config,
)
from roger_daemon.learner.synthetic import subtask_stream

pytestmark = pytest.mark.integration

STREAM = subtask_stream(60)


@pytest.fixture(scope="module")
def daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, Path]]:
    work = tmp_path_factory.mktemp("tools")
    port = free_port()
    cfg = write_config(work / "d.toml", port=port, workdir=work,
                       daemon={"id": "tooltest", "status_hz": 5.0})  # quicker answers
    proc = DaemonProcess(cfg)
    try:
        proc.wait_ready()
        yield f"tcp/127.0.0.1:{port}", work
    finally:
        code, _ = proc.terminate(timeout=30)
        assert code == 0, proc.log()


def roger(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_list_names_the_daemon_and_its_robot(daemon: tuple[str, Path],
                                              capsys: pytest.CaptureFixture[str]) -> None:
    ep, _ = daemon
    code, out, err = roger(capsys, "list", "--json", "--connect", ep, "--timeout", "10",
                           "--wait", "0.6")
    assert code == 0, err
    listed = json.loads(out)["daemons"]
    assert [d["id"] for d in listed] == ["tooltest"]
    assert [r["robot"] for r in listed[0]["robots"]] == ["aibo"]
    assert listed[0]["robots"][0]["level"] in ("OK", "WARN", "ERROR")
    assert listed[0]["level"] == listed[0]["robots"][0]["level"]


def test_status_prints_the_robot_with_a_level(daemon: tuple[str, Path],
                                              capsys: pytest.CaptureFixture[str]) -> None:
    ep, _ = daemon
    code, out, err = roger(capsys, "status", "aibo", "--json", "--connect", ep,
                           "--timeout", "10")
    assert code == 0, err
    st = json.loads(out)
    assert st["robot"] == "aibo" and st["daemon"] == "tooltest"
    assert st["level"] == st["info"]["level"] and st["level"] in ("OK", "WARN")
    code, out, _ = roger(capsys, "status", "aibo", "--connect", ep, "--timeout", "10")
    assert code == 0 and out.startswith("aibo  ") and "daemon tooltest" in out


def test_status_of_an_unserved_robot_fails_within_the_deadline(
    daemon: tuple[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    ep, _ = daemon
    code, out, err = roger(capsys, "status", "nobody", "--connect", ep, "--timeout", "1.5")
    assert code == 1 and out == "" and "no status from robot 'nobody'" in err


def _feed(ep: str, stop: threading.Event, robot: str = "aibo") -> None:
    client = Client(ep, robot=robot, daemon_id="tooltest")
    try:
        client.wait_daemon()
        tick = 0
        while not stop.is_set():
            i = tick % len(STREAM.x)
            client.perception(tick, STREAM.x[i])
            client.action(tick, STREAM.y[i], "seek")
            tick += 1
            time.sleep(0.02)
    finally:
        client.close()


@pytest.fixture
def feeding(daemon: tuple[str, Path]) -> Iterator[str]:
    ep, _ = daemon
    stop = threading.Event()
    th = threading.Thread(target=_feed, args=(ep, stop), daemon=True)
    th.start()
    yield ep
    stop.set()
    th.join(30)


def test_echo_decodes_predictions(feeding: str, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = roger(capsys, "echo", "aibo/prediction", "--json", "--count", "3",
                           "--connect", feeding, "--timeout", "15")
    assert code == 0, err
    lines = [json.loads(line) for line in out.splitlines()]
    assert len(lines) == 3
    for line in lines:
        assert line["key"] == "roger/aibo/prediction"
        msg = line["msg"]
        assert len(msg["mean"]) == 9 and all(v > 0 for v in msg["var"])
        assert msg["mode"] in ("learn+predict", "predict")


def test_hz_measures_the_prediction_stream(feeding: str,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = roger(capsys, "hz", "roger/aibo/prediction", "--json", "--duration", "2.5",
                           "--every", "0.5", "--connect", feeding)
    assert code == 0, err
    reports = [json.loads(line) for line in out.splitlines()]
    assert reports and reports[-1]["messages"] >= 5
    # the feeder sends one perception per >= 20 ms (lockstep: one prediction each)
    assert 0 < reports[-1]["rate_hz"] <= 100


def test_control_mode_reset_checkpoint_are_confirmed(
    daemon: tuple[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    ep, work = daemon
    common = ("--connect", ep, "--timeout", "15")
    code, out, err = roger(capsys, "control", "aibo", "mode", "learn", *common)
    assert code == 0 and "mode learn, confirmed by daemon tooltest" in out, err
    code, out, err = roger(capsys, "status", "aibo", "--json", *common)
    assert json.loads(out)["mode"] == "learn"
    code, out, err = roger(capsys, "control", "aibo", "checkpoint", *common)
    assert code == 0, err
    assert "checkpoint" in out and list((work / "checkpoints" / "aibo").glob("ckpt-*.npz"))
    code, out, err = roger(capsys, "control", "aibo", "reset", *common)
    assert code == 0 and "reset (0 updates)" in out, err
    code, out, err = roger(capsys, "control", "aibo", "mode", "learn+predict", *common)
    assert code == 0, err


def test_robot_client_checkpoint_returns_once_the_file_is_on_disk(
        daemon: tuple[str, Path]) -> None:
    """RobotClient.checkpoint waits for the write, not only for the confirmation (whose status
    still names the previous checkpoint, or none), and the daemon names it by an absolute
    path whatever its working directory (issue 56, item 7)."""
    ep, work = daemon
    with RobotClient(ep, robot="aibo", daemon_id="tooltest") as robot:
        robot.wait_daemon(30)
        for _ in range(2):
            before = int(robot.wait_status(timeout=30).info.get("checkpoints_written", 0))
            st = robot.checkpoint(30)
            assert st.info["checkpoints_written"] == before + 1, st.info
            path = Path(str(st.info["checkpoint"]))
            newest = sorted((work / "checkpoints" / "aibo").glob("ckpt-*.npz"))[-1]
            assert path.is_absolute() and path == newest.absolute(), (path, newest)


def test_robot_client_on_a_given_session_leaves_it_open(daemon: tuple[str, Path]) -> None:
    """What roger control does: RobotClient on the session the connection options opened,
    the robot's sizes unknown (dims=None); closing the client leaves the session to its
    owner."""
    from roger_daemon.config import ZenohSettings
    from roger_daemon.transport import open_session

    ep, _ = daemon
    session = open_session(ZenohSettings(connect=(ep,), listen=()))
    try:
        with RobotClient(session=session, robot="aibo", dims=None) as client:
            assert client.wait_status(timeout=30).robot == "aibo"
        replies = session.liveliness().get(keys.daemon_liveliness_all(), timeout=10)
        assert any(r.ok is not None for r in replies)  # still open, still connected
        assert client.errors == []
    finally:
        session.close()


def test_checkpoint_outcome_is_decided_by_the_status_counters() -> None:
    before = {"checkpoints_written": 2, "checkpoint_errors": 0}
    assert checkpoint_outcome(before, before) is None
    assert checkpoint_outcome(before, {**before, "checkpoints_written": 3}) == "written"
    assert checkpoint_outcome(before, {**before, "checkpoint_errors": 1}) == "failed"
    assert checkpoint_outcome({}, {"checkpoints_written": 1}) == "written"


def test_control_without_confirmation_exits_non_zero(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """A 'daemon' that publishes status for robot ghost but never confirms anything."""
    import zenoh

    from roger_daemon.config import ZenohSettings
    from roger_daemon.transport import open_session

    ep = f"tcp/127.0.0.1:{free_port()}"
    session = open_session(ZenohSettings(listen=(ep,)))
    stop = threading.Event()

    def impostor() -> None:
        while not stop.is_set():
            st = Status("ghost", 0, 0.0, daemon="mute", mode="learn", ticks=0, updates=0,
                        updates_per_s=0.0, experts=0, queue_depth=0, dropped=0)
            session.put(keys.status("ghost"), encode(st),
                        congestion_control=zenoh.CongestionControl.DROP)
            stop.wait(0.2)

    th = threading.Thread(target=impostor, daemon=True)
    th.start()
    try:
        code, out, err = roger(capsys, "control", "ghost", "mode", "predict",
                               "--connect", ep, "--timeout", "2")
    finally:
        stop.set()
        th.join(10)
        session.close()
    assert code == 1 and out == ""
    assert "did not confirm" in err


def test_control_rejects_a_bad_request_with_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = roger(capsys, "control", "aibo", "mode", "fly")
    assert code == 2 and "one of learn, predict, learn+predict, pause" in err and "'fly'" in err
    with pytest.raises(SystemExit) as exc:
        main(["control", "aibo", "explode"])
    assert exc.value.code == 2


@pytest.mark.slow  # ~6 s: waits for the 3 s staleness threshold (make test-all)
def test_status_watch_reports_stale_when_statuses_stop() -> None:
    import signal
    import subprocess
    import sys

    from roger_daemon.config import ZenohSettings
    from roger_daemon.transport import open_session

    ep = f"tcp/127.0.0.1:{free_port()}"
    session = open_session(ZenohSettings(listen=(ep,)))
    with interruptible_child():  # it is sent SIGINT below
        watch = subprocess.Popen([sys.executable, "-m", "roger_daemon", "status", "ghost",
                                  "--watch", "--json", "--connect", ep],
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert watch.stdout is not None
        st = Status("ghost", 0, 0.0, daemon="mute", mode="learn", ticks=0, updates=0,
                    updates_per_s=0.0, experts=0, queue_depth=0, dropped=0,
                    info={"level": "OK", "level_reasons": ""})
        deadline = time.monotonic() + 60
        first = None
        while first is None and time.monotonic() < deadline:  # until the watcher hears one
            session.put(keys.status("ghost"), encode(st))
            time.sleep(0.3)
            first = json.loads(watch.stdout.readline()) if _readable(watch.stdout) else None
        assert first is not None and first["level"] == "OK"
        # no more statuses: the next line must say STALE
        line = json.loads(watch.stdout.readline())
        while line["level"] != "STALE":
            line = json.loads(watch.stdout.readline())
        assert line["age_s"] > 3.0 and "no status for" in line["info"]["level_reasons"]
        watch.send_signal(signal.SIGINT)
        _, err = watch.communicate(timeout=30)
    finally:
        if watch.poll() is None:
            watch.kill()
            watch.communicate()
        session.close()
    assert watch.returncode == 130 and "Traceback" not in err


def _readable(stream: object) -> bool:
    import select

    return bool(select.select([stream], [], [], 0.0)[0])


def test_list_without_a_daemon_exits_1(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = roger(capsys, "list", "--connect", f"tcp/127.0.0.1:{free_port()}",
                           "--timeout", "1", "--wait", "0.2")
    assert code == 1 and out == "" and "no daemon answered within 1 s" in err
