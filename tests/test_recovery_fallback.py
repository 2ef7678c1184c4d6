"""Start-up falls back across every copy: all checkpoints, the write-ahead log and the session
logs, so that no acknowledged pair is lost while a copy survives, and status says what came
from where (docs/durability.md, *Torn and corrupt records*). In process, with the daemon's own
start-up and loop (tests/test_recovery.py's ``Life``), real checkpoints, log and recordings."""

from __future__ import annotations

import struct
from pathlib import Path

from test_recovery import Life, assert_same, make_cfg, reference

from roger_daemon.daemon.checkpoint import Checkpoint, list_checkpoints, read_checkpoint
from roger_daemon.daemon.wal import read_log, segments, wal_dir


def _frames(path: Path) -> list[int]:
    data = path.read_bytes()
    out, pos = [], 0
    while pos + 8 <= len(data) and struct.unpack_from("<I", data, pos)[0]:
        out.append(pos)
        pos += 8 + struct.unpack_from("<I", data, pos)[0]
    return out


def _spoil(path: Path) -> None:
    """An unreadable checkpoint: its second half gone."""
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def test_a_flipped_byte_in_the_log_costs_nothing_with_the_recordings(tmp_path: Path) -> None:
    a = Life(make_cfg(tmp_path, tmp_path / "logs1", wal=True))
    a.pairs(range(50))  # checkpoints at 20 and 40; pairs 40..49 only in the newest segment
    a.flush()
    logs2 = a.crash(tmp_path / "logs2")
    d = wal_dir(tmp_path / "ckpt", "sim")
    _, last = segments(d)[-1]
    frames = _frames(last)
    data = bytearray(last.read_bytes())
    data[frames[5] + 20] ^= 0xFF  # pair 45, in the middle of the segment
    last.write_bytes(bytes(data))
    (dmg,) = read_log(d).damage
    assert dmg.offset == frames[5] and len(dmg.lost_seqs) == 1
    b = Life(make_cfg(tmp_path, logs2, wal=True))
    assert b.rt.updates == 50 and b.rt.recovery_lost == 0
    assert_same(b.rt.model, reference(list(range(50))))
    info = b.service.status_of(b.rt, b.clock.mono).info
    assert "9 pairs and 0 resets from the write-ahead log" in info["recovery"]
    assert "1 pairs from the session logs" in info["recovery"]
    assert f"offset {frames[5]}" in info["recovery"] and last.name in info["recovery"]
    b.stop()


def test_without_the_recordings_the_lost_pair_is_named_and_the_rest_kept(tmp_path: Path) -> None:
    a = Life(make_cfg(tmp_path, tmp_path / "logs1", wal=True))
    a.pairs(range(50))
    logs2 = tmp_path / "empty"  # no session logs survive
    logs2.mkdir()
    d = wal_dir(tmp_path / "ckpt", "sim")
    _, last = segments(d)[-1]
    frames = _frames(last)
    data = bytearray(last.read_bytes())
    data[frames[5] + 20] ^= 0xFF
    last.write_bytes(bytes(data))
    b = Life(make_cfg(tmp_path, logs2, wal=True))
    assert b.rt.updates == 49 and b.rt.recovery_lost == 1
    info = b.service.status_of(b.rt, b.clock.mono).info
    assert "1 pairs lost (no intact copy)" in info["recovery"]
    level, reasons = b.service.health["sim"].assess(
        b.service.status_of(b.rt, b.clock.mono).to_map(), b.clock.mono)
    assert level == "WARN" and "1 pairs lost at start-up" in reasons
    b.stop()


def _two_newest_spoiled(tmp_path: Path) -> tuple[Path, list[Path], Checkpoint]:
    """A life of 100 pairs (checkpoints every 20, 5 kept) killed; its two newest checkpoints
    unreadable: the next life's logs, the checkpoints and the third one read."""
    a = Life(make_cfg(tmp_path, tmp_path / "logs1", wal=True))
    a.pairs(range(100))
    a.flush()
    logs2 = a.crash(tmp_path / "logs2")
    ckpts = list_checkpoints(tmp_path / "ckpt", "sim")
    for p in ckpts[:2]:
        _spoil(p)
    return logs2, ckpts, read_checkpoint(ckpts[2])


def test_two_unreadable_checkpoints_fall_back_to_the_third_and_lose_nothing(
        tmp_path: Path) -> None:
    logs2, ckpts, third = _two_newest_spoiled(tmp_path)
    b = Life(make_cfg(tmp_path, logs2, wal=True))
    assert b.rt.updates == 100
    assert_same(b.rt.model, reference(list(range(100))))
    info = b.service.status_of(b.rt, b.clock.mono).info
    assert info["recovery"].startswith(f"checkpoint {ckpts[2].name} ({third.meta.updates} "
                                       "updates), 2 newer checkpoints unreadable")
    assert f"{100 - third.meta.updates} pairs and 0 resets from the write-ahead log" in \
        info["recovery"]
    b.stop()


def test_a_log_pruned_past_the_fallback_checkpoint_is_filled_from_the_recordings(
        tmp_path: Path) -> None:
    logs2, ckpts, third = _two_newest_spoiled(tmp_path)
    assert third.meta.wal_seq is not None
    d = wal_dir(tmp_path / "ckpt", "sim")
    segs = segments(d)
    for (_, path), (nxt, _) in zip(segs, segs[1:], strict=False):  # an older daemon's pruning:
        if nxt - 1 <= third.meta.wal_seq + 20:  # the log kept one checkpoint's worth only
            path.unlink()
    b = Life(make_cfg(tmp_path, logs2, wal=True))
    assert b.rt.updates == 100 and b.rt.recovery_lost == 0
    assert_same(b.rt.model, reference(list(range(100))))
    assert "pairs from the session logs" in b.rt.recovery
    b.stop()
