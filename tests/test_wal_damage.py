"""A damaged write-ahead log: every record its CRC proves intact is kept, before and after the
damage, and the damage is named with its offset (docs/durability.md, *Torn and corrupt
records*)."""

from __future__ import annotations

import logging
import struct
from pathlib import Path

import numpy as np
import pytest

from protocols.messages import Dims
from roger_daemon.config import parse_config
from roger_daemon.daemon.checkpoint import array_digest
from roger_daemon.daemon.main import make_model
from roger_daemon.daemon.robot import RobotRuntime
from roger_daemon.daemon.wal import WalRecord, WriteAheadLog, read_log, replay_into, segments

N = 600


def _pair(i: int) -> tuple[np.ndarray, np.ndarray]:
    return np.array([i / N]), np.array([np.sqrt(i / N)])


def _write_log(d: Path, n: int = N) -> list[int]:
    """A log of a fresh record and ``n`` pairs; the byte offset of every frame."""
    w = WriteAheadLog(d, 0)
    w.append_fresh()
    for i in range(n):
        w.append_pair(i, 1000 + i, *_pair(i), "seek")
    w.close()
    (_, path), = segments(d)
    data = path.read_bytes()
    offsets, pos = [], 0
    while True:
        length, _ = struct.unpack_from("<II", data, pos)
        if length == 0:
            return offsets
        offsets.append(pos)
        pos += 8 + length


def _flip(d: Path, offset: int) -> Path:
    (_, path), = segments(d)
    data = bytearray(path.read_bytes())
    data[offset] ^= 0xFF
    path.write_bytes(bytes(data))
    return path


def _runtime() -> RobotRuntime:
    robot = parse_config({"robots": [{"id": "sim", "x_dim": 1, "y_dim": 1}]}).robots[0]
    return RobotRuntime("sim", Dims(1, 1), make_model(robot), lambda: make_model(robot))


@pytest.mark.parametrize("where", [0, 5, 30], ids=["length", "crc", "payload"])
def test_one_flipped_byte_in_the_middle_costs_one_record(tmp_path: Path, where: int) -> None:
    offsets = _write_log(tmp_path)
    bad = 1 + N // 2  # frame 301: pair 300 (frame 0 is the fresh record)
    path = _flip(tmp_path, offsets[bad] + where)
    got = read_log(tmp_path)
    assert [r.seq for r in got.records] == [s for s in range(N + 1) if s != bad]
    (dmg,) = got.damage
    assert (dmg.path, dmg.offset, dmg.length) == (path, offsets[bad],
                                                  offsets[bad + 1] - offsets[bad])
    assert list(dmg.lost_seqs) == [bad] and not dmg.torn_tail
    assert dmg.describe() == (f"{path.name} offset {offsets[bad]}: corrupt record(s), seq "
                              f"{bad}..{bad} ({dmg.length} bytes skipped)")


def test_a_damaged_tail_is_a_torn_tail(tmp_path: Path) -> None:
    offsets = _write_log(tmp_path, 10)
    _flip(tmp_path, offsets[-1] + 20)
    got = read_log(tmp_path)
    assert len(got.records) == 10 and got.damage[0].torn_tail
    assert got.damage[0].offset == offsets[-1]


def test_replay_keeps_every_intact_pair_and_takes_the_lost_one_from_a_copy(
        tmp_path: Path) -> None:
    offsets = _write_log(tmp_path)
    _flip(tmp_path, offsets[1 + N // 2] + 30)  # pair 300
    without = _runtime()
    rep = replay_into(without, tmp_path, -1)
    assert (rep.pairs, rep.lost, rep.copied, without.updates) == (N - 1, 1, 0, N - 1)
    assert rep.notes == [f"pairs 300..300 (before record {2 + N // 2}, tick 1301) are lost: "
                         "no intact copy"]
    asked: list[tuple[range, int | None]] = []

    def copies(wanted: range, anchor: WalRecord | None) -> list[WalRecord]:
        asked.append((wanted, None if anchor is None else anchor.index))
        return [WalRecord("pair", -1, i, 1000 + i, *_pair(i), "seek")
                for i in range(wanted.start, min(wanted.stop, N))]

    full = _runtime()  # as if restored from a checkpoint of the fresh model (seq 0)
    rep = replay_into(full, tmp_path, 0, copies=copies)
    assert (rep.pairs, rep.lost, rep.copied, full.updates) == (N - 1, 0, 1, N)
    assert asked == [(range(300, 301), 301), (range(N, 1 << 40), None)]  # the gap, the tail
    ref = make_model(parse_config({"robots": [{"id": "sim", "x_dim": 1,
                                               "y_dim": 1}]}).robots[0])
    for i in range(N):
        ref.learn_one(*_pair(i))
    assert array_digest(full.model.state_dict()) == array_digest(ref.state_dict())


def test_a_lost_reset_record_is_inferred_from_pair_zero(tmp_path: Path,
                                                        caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO)
    w = WriteAheadLog(tmp_path, 0)
    w.append_fresh()
    for i in range(5):
        w.append_pair(i, i, *_pair(i), "")
    w.append_fresh()
    for i in range(3):
        w.append_pair(i, 10 + i, *_pair(i), "")
    w.close()
    (_, path), = segments(tmp_path)
    recs = read_log(tmp_path).records
    assert len(recs) == 10
    data = path.read_bytes()
    # the second fresh record: find its frame by re-scanning the offsets
    pos, frames = 0, []
    while struct.unpack_from("<II", data, pos)[0]:
        frames.append(pos)
        pos += 8 + struct.unpack_from("<II", data, pos)[0]
    _flip(tmp_path, frames[6] + 10)
    rt = _runtime()
    rep = replay_into(rt, tmp_path, -1)
    assert rep.fresh == 2 and rep.pairs == 8 and rt.updates == 3 and rep.lost == 0
