"""The loop's single wait: frames read as they arrive from non-blocking pipes
(``FrameReader``) and an inbox whose wait also ends on a readable file descriptor or on a
``put`` from another thread (docs/fleet.md, *One wait*). Real pipes, real threads."""

from __future__ import annotations

import os
import struct
import threading
import time
from collections.abc import Iterator

import msgpack
import numpy as np
import pytest

from roger_daemon.daemon.worker import FrameReader, pack_arrays, unpack_arrays, write_frame
from roger_daemon.transport import Inbox, Incoming

# generous deadlines: only a wait that never ends fails them (no timing is asserted)
LONG_S = 60.0


@pytest.fixture
def pipe() -> Iterator[tuple[object, int]]:
    """(non-blocking unbuffered reading end, writing fd)."""
    r, w = os.pipe()
    os.set_blocking(r, False)
    raw = os.fdopen(r, "rb", buffering=0)
    yield raw, w
    raw.close()
    try:
        os.close(w)
    except OSError:
        pass


def _frame(msg: dict[str, object]) -> bytes:
    payload = msgpack.packb(msg, use_bin_type=True)
    return struct.pack("<I", len(payload)) + payload


def test_frames_split_at_every_byte_come_out_whole_and_in_order(pipe) -> None:
    raw, w = pipe
    reader = FrameReader(raw)
    msgs = [{"op": "learn", "n": i, "x": bytes(range(i))} for i in range(5)]
    data = b"".join(_frame(m) for m in msgs)
    got = []
    for i in range(len(data)):  # one byte at a time: every split of header and payload
        os.write(w, data[i: i + 1])
        got += reader.read()
    assert got == msgs
    assert reader.read() == []  # nothing more: returns at once
    assert not reader.eof


def test_several_frames_in_one_read_and_end_of_input(pipe) -> None:
    raw, w = pipe
    reader = FrameReader(raw)
    os.write(w, _frame({"a": 1}) + _frame({"b": 2}) + _frame({"c": 3})[:3])
    assert reader.read() == [{"a": 1}, {"b": 2}]
    os.close(w)
    assert reader.read() == []
    assert reader.eof


def test_a_large_frame_written_by_write_frame_arrives_intact(pipe) -> None:
    raw, w = pipe
    reader = FrameReader(raw)
    state = {"C": np.arange(200_000, dtype=np.float64).reshape(400, 500)}  # 1.6 MB > a pipe
    got: list[dict[str, object]] = []

    def send() -> None:
        with os.fdopen(os.dup(w), "wb") as f:
            write_frame(f, {"state": pack_arrays(state)})

    t = threading.Thread(target=send)
    t.start()
    deadline = time.monotonic() + LONG_S
    while not got and time.monotonic() < deadline:
        got = reader.read()
    t.join(LONG_S)
    assert len(got) == 1
    out = unpack_arrays(got[0]["state"])
    np.testing.assert_array_equal(out["C"], state["C"])


@pytest.mark.parametrize("bad", [
    struct.pack("<I", 0),  # an empty payload is no map
    struct.pack("<I", 3) + b"\xc1\xc1\xc1",  # never-used msgpack bytes
    struct.pack("<I", 3) + msgpack.packb([1, 2]),  # an array, not a map
    struct.pack("<I", (1 << 30) + 1),  # larger than any frame
])
def test_a_bad_frame_raises_value_error(pipe, bad: bytes) -> None:
    raw, w = pipe
    os.write(w, bad)
    with pytest.raises(ValueError):
        FrameReader(raw).read()


def _item(i: int) -> Incoming:
    return Incoming(f"k{i}", b"x", 1, i, i)


def test_inbox_get_returns_queued_items_without_waiting() -> None:
    inbox = Inbox(4)
    inbox.put(_item(1))
    inbox.put(_item(2))
    assert inbox.get(LONG_S).key == "k1"  # type: ignore[union-attr]
    assert inbox.get(0).key == "k2"  # type: ignore[union-attr]
    assert inbox.get(0) is None
    inbox.close()


def test_inbox_overflow_is_counted_not_blocking() -> None:
    inbox = Inbox(2)
    for i in range(5):
        inbox.put(_item(i))
    assert inbox.overflow == 3
    assert len(inbox) == 2
    inbox.close()


@pytest.mark.parametrize("with_fds", [True, False])
def test_a_put_from_another_thread_ends_the_wait(with_fds: bool) -> None:
    """With descriptors the self-pipe wakes the select; without, the queue's own wait."""
    inbox = Inbox(4)
    r, w = os.pipe()  # a worker pipe that stays silent
    try:
        t = threading.Timer(0.05, inbox.put, args=(_item(7),))
        t.start()
        t0 = time.monotonic()
        got = inbox.get(LONG_S, fds=[r] if with_fds else ())
        t.join()
        assert got is not None and got.key == "k7"
        assert time.monotonic() - t0 < LONG_S / 2  # woken, not timed out
    finally:
        os.close(r)
        os.close(w)
        inbox.close()


def test_a_readable_descriptor_ends_the_wait_with_none() -> None:
    inbox = Inbox(4)
    r, w = os.pipe()
    try:
        os.write(w, b"reply")
        t0 = time.monotonic()
        assert inbox.get(LONG_S, fds=[r]) is None
        assert time.monotonic() - t0 < LONG_S / 2
    finally:
        os.close(r)
        os.close(w)
        inbox.close()


def test_a_put_while_the_loop_is_busy_writes_no_wake_byte() -> None:
    """Only a waiting loop is woken: items put between waits cost no system call, and the
    next wait does not end early on a stale wake."""
    inbox = Inbox(4)
    inbox.put(_item(1))
    assert inbox.get(0) is not None
    readable = [fd for fd in (inbox._wake_r,) if _has_data(fd)]
    assert readable == []
    inbox.close()


def _has_data(fd: int) -> bool:
    import select

    return bool(select.select([fd], [], [], 0)[0])
