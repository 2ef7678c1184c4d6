"""sd_notify over a real unix datagram socket bound by the test."""

from __future__ import annotations

import os
import socket
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from roger_daemon.daemon.sdnotify import Notifier


@pytest.fixture
def listener(tmp_path: Path) -> Iterator[tuple[socket.socket, str]]:
    path = str(tmp_path / "notify.sock")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    sock.settimeout(2.0)
    yield sock, path
    sock.close()


def test_messages_reach_the_socket(listener: tuple[socket.socket, str]) -> None:
    sock, path = listener
    n = Notifier.from_env({"NOTIFY_SOCKET": path})
    assert n.enabled
    assert n.ready("serving aibo")
    assert sock.recv(1024) == b"READY=1\nSTATUS=serving aibo"
    assert n.status("aibo: 3 experts, naïve newline\nstripped")
    assert sock.recv(1024).decode() == "STATUS=aibo: 3 experts, naïve newline stripped"
    assert n.stopping()
    assert sock.recv(1024) == b"STOPPING=1"
    n.close()


def test_abstract_namespace_address() -> None:
    name = f"roger-test-{os.getpid()}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind("\0" + name)
    sock.settimeout(2.0)
    try:
        n = Notifier.from_env({"NOTIFY_SOCKET": "@" + name})
        assert n.ready()
        assert sock.recv(64) == b"READY=1"
    finally:
        sock.close()


def test_watchdog_pings_at_half_the_interval(listener: tuple[socket.socket, str]) -> None:
    sock, path = listener
    n = Notifier.from_env({"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "2000000"})
    assert n.watchdog_ns == 2_000_000_000
    assert n.watchdog(10_000_000_000)  # first ping at once
    assert sock.recv(64) == b"WATCHDOG=1"
    assert not n.watchdog(10_900_000_000)  # 0.9 s later: not yet due
    assert n.watchdog(11_000_000_000)  # 1.0 s = half the interval
    assert sock.recv(64) == b"WATCHDOG=1"


def test_watchdog_for_another_pid_is_ignored(listener: tuple[socket.socket, str]) -> None:
    _, path = listener
    n = Notifier.from_env({"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "2000000",
                           "WATCHDOG_PID": str(os.getpid() + 1)})
    assert n.watchdog_ns is None and not n.watchdog(0)


def test_without_systemd_everything_is_a_no_op() -> None:
    n = Notifier.from_env({})
    assert not n.enabled
    assert not n.ready() and not n.watchdog(0) and not n.stopping()


def test_a_vanished_socket_does_not_raise(tmp_path: Path) -> None:
    n = Notifier.from_env({"NOTIFY_SOCKET": str(tmp_path / "gone.sock")})
    assert n.send("READY=1") is False


def test_extend_start_asks_for_more_start_up_time(listener: tuple[socket.socket, str]) -> None:
    sock, path = listener
    n = Notifier.from_env({"NOTIFY_SOCKET": path})
    assert n.extend_start(30)
    assert sock.recv(64) == b"EXTEND_TIMEOUT_USEC=30000000"
    assert n.extend_start(0.0000001)  # never 0, which systemd reads as "no time at all"
    assert sock.recv(64) == b"EXTEND_TIMEOUT_USEC=1"


def test_starting_keeps_extending_until_the_block_ends(
        listener: tuple[socket.socket, str]) -> None:
    sock, path = listener
    sock.settimeout(30.0)  # generous: the helper thread may be scheduled late on a busy machine
    n = Notifier.from_env({"NOTIFY_SOCKET": path})
    with n.starting("compiling", every_s=0.01, extend_s=2.5):
        got = [sock.recv(256) for _ in range(4)]  # the status, then repeated extensions
    assert got == [b"STATUS=compiling"] + [b"EXTEND_TIMEOUT_USEC=2500000"] * 3
    while True:  # whatever the helper sent before it stopped
        sock.settimeout(0.2)
        try:
            sock.recv(256)
        except TimeoutError:
            break
    assert not [t for t in threading.enumerate() if t.name == "sd-notify-extend"]
    assert n.extend_start(1)  # the notifier is still usable
    assert sock.recv(64) == b"EXTEND_TIMEOUT_USEC=1000000"


def test_starting_without_systemd_runs_the_block_and_sends_nothing() -> None:
    n = Notifier.from_env({})
    ran = []
    with n.starting("compiling", every_s=0.01):
        ran.append(True)
    assert ran == [True]
    assert not [t for t in threading.enumerate() if t.name == "sd-notify-extend"]


def test_starting_stops_its_helper_when_the_block_raises(
        listener: tuple[socket.socket, str]) -> None:
    _, path = listener
    n = Notifier.from_env({"NOTIFY_SOCKET": path})
    with pytest.raises(RuntimeError, match="boom"), n.starting("x", every_s=0.01):
        raise RuntimeError("boom")
    assert not [t for t in threading.enumerate() if t.name == "sd-notify-extend"]
