"""Retention of checkpoints and recordings: bytes and age limits, what is never deleted, and
the config keys that set them."""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import pytest

from roger_daemon.config import ConfigError, parse_config
from roger_daemon.daemon.checkpoint import CheckpointMeta, list_checkpoints, write_checkpoint
from roger_daemon.daemon.retention import prune_oldest, prune_recordings

META = CheckpointMeta(reason="test", updates=0, x_dim=1, y_dim=1)


def _file(path: Path, size: int, age_s: float = 0.0) -> Path:
    path.write_bytes(b"\0" * size)
    t = time.time() - age_s
    os.utime(path, (t, t))
    return path


def test_prune_oldest_by_bytes_keeps_the_protected_file(tmp_path: Path) -> None:
    files = [_file(tmp_path / f"f{i}", 100) for i in range(5)]
    gone = prune_oldest(files, max_bytes=250, keep=[files[0]])
    assert gone == files[1:4]  # oldest first, f0 protected; 200 bytes left
    assert [p.exists() for p in files] == [True, False, False, False, True]


def test_prune_oldest_by_age(tmp_path: Path) -> None:
    old = _file(tmp_path / "old", 10, age_s=3 * 86400)
    new = _file(tmp_path / "new", 10)
    assert prune_oldest([old, new], max_age_s=86400) == [old]
    assert new.exists() and prune_oldest([new]) == []  # no limits: nothing deleted


def test_checkpoint_retention_by_bytes_never_deletes_the_newest(tmp_path: Path) -> None:
    model = {"w": np.zeros(10_000)}  # ~80 kB per checkpoint
    for _ in range(4):
        write_checkpoint(tmp_path, "r", model, {}, META, keep=5, max_bytes=200_000)
    kept = list_checkpoints(tmp_path, "r")
    assert [p.name for p in kept] == ["ckpt-00000004.npz", "ckpt-00000003.npz"]
    write_checkpoint(tmp_path, "r", model, {}, META, keep=5, max_bytes=1)
    assert [p.name for p in list_checkpoints(tmp_path, "r")] == ["ckpt-00000005.npz"]


def test_recording_retention_deletes_oldest_sessions_first(tmp_path: Path) -> None:
    a = _file(tmp_path / "roger-aibo-20260101T000000Z.mcap", 1000, age_s=300)
    a_dmg = _file(tmp_path / "roger-aibo-20260101T000000Z.mcap.damaged", 500, age_s=300)
    b = _file(tmp_path / "roger-aibo-20260102T000000Z.mcap", 1000, age_s=200)
    cur = _file(tmp_path / "roger-aibo-20260103T000000Z.mcap", 1000, age_s=100)
    other = _file(tmp_path / "roger-spot-20260101T000000Z.mcap", 5000, age_s=900)
    mine = _file(tmp_path / "notes.txt", 10, age_s=900)
    gone = prune_recordings(tmp_path, "aibo", max_bytes=2000, keep=[cur])
    assert gone == [a, a_dmg]
    assert b.exists() and cur.exists() and other.exists() and mine.exists()
    assert prune_recordings(tmp_path, "aibo", max_age_s=150, keep=[cur]) == [b]
    assert cur.exists()


@pytest.mark.parametrize("section,key,value,expected", [
    ("checkpoint", "max_bytes", -1, "an integer >= 0"),
    ("checkpoint", "max_age_days", "old", "a number >= 0"),
    ("recording", "max_bytes", 1.5, "an integer >= 0"),
    ("checkpoint", "wal_commit_ms", 200, "a number in (0, 50]"),
    ("checkpoint", "wal", "yes", "true or false"),
    ("checkpoint", "wal_reserve_kb", 32, "an integer >= 64"),
    ("checkpoint", "wal_reserve_kb", 1 << 20, "an integer in [64, 65536]"),
])
def test_retention_and_durability_keys_are_validated(section: str, key: str, value: object,
                                                     expected: str) -> None:
    with pytest.raises(ConfigError) as err:
        parse_config({section: {key: value}})
    assert f"{section}.{key} must be {expected}" in str(err.value)
