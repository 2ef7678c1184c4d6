"""Checkpoints: atomic, versioned named arrays, verified on load, never pickled."""

from __future__ import annotations

import json
import logging
import zipfile
from pathlib import Path

import numpy as np
import pytest

from roger_daemon.daemon import checkpoint as ck
from roger_daemon.daemon.checkpoint import (
    CHECKPOINT_VERSION,
    CheckpointError,
    CheckpointMeta,
    list_checkpoints,
    load_newest,
    read_checkpoint,
    write_checkpoint,
)
from roger_daemon.learner import Roger, RogerParams, load_model
from roger_daemon.learner.synthetic import subtask_stream


def model_state(n: int = 15) -> dict[str, np.ndarray]:
    s = subtask_stream(n)
    m = Roger(d_x=23, d_y=9, params=RogerParams(), seed=3)
    for x, y in zip(s.x, s.y, strict=True):
        m.learn_one(x, y)
    return m.state_dict()


DAEMON = {"label_vocab": np.array(["seek", "aim"]), "label_codes": np.array([0, 1, 1])}


def meta(updates: int) -> CheckpointMeta:
    return CheckpointMeta(reason="test", updates=updates, x_dim=23, y_dim=9)


def test_round_trip_and_model_continues_identically(tmp_path: Path) -> None:
    state = model_state()
    path, written = write_checkpoint(tmp_path, "aibo", state, DAEMON, meta(15))
    assert path == tmp_path / "aibo" / "ckpt-00000001.npz"
    back = read_checkpoint(path)
    assert back.meta.version == CHECKPOINT_VERSION and back.meta.updates == 15
    assert back.meta.model_digest == written.model_digest == ck.array_digest(state)
    for k in state:
        np.testing.assert_array_equal(back.model[k], state[k])
    assert back.daemon["label_vocab"].tolist() == ["seek", "aim"]
    a, b = load_model(state), load_model(back.model)
    x = subtask_stream(20).x[-1]
    np.testing.assert_array_equal(a.predict_one(x).mean, b.predict_one(x).mean)
    # no pickle anywhere: every member loads with allow_pickle=False
    with np.load(path, allow_pickle=False) as npz:
        assert all(npz[name].dtype != object for name in npz.files)
    assert not list(path.parent.glob(".*tmp*"))  # no temporary left behind


def test_object_arrays_are_refused(tmp_path: Path) -> None:
    with pytest.raises(CheckpointError, match="object dtype"):
        write_checkpoint(tmp_path, "aibo", {"bad": np.array([{"a": 1}], dtype=object)}, {},
                         meta(0))
    assert list_checkpoints(tmp_path, "aibo") == []


def test_sequence_numbers_and_pruning(tmp_path: Path) -> None:
    state = {"w": np.arange(3.0)}
    for i in range(7):
        write_checkpoint(tmp_path, "aibo", state, {}, meta(i), keep=3)
    files = list_checkpoints(tmp_path, "aibo")
    assert [f.name for f in files] == ["ckpt-00000007.npz", "ckpt-00000006.npz",
                                       "ckpt-00000005.npz"]


@pytest.mark.parametrize("damage", ["truncate", "garbage", "flip", "empty"])
def test_damaged_files_are_detected(tmp_path: Path, damage: str) -> None:
    path, _ = write_checkpoint(tmp_path, "aibo", {"w": np.arange(1000.0)}, {}, meta(1))
    data = bytearray(path.read_bytes())
    if damage == "truncate":
        path.write_bytes(bytes(data[: len(data) // 2]))
    elif damage == "garbage":
        path.write_bytes(b"not a zip at all" * 10)
    elif damage == "flip":
        data[len(data) // 3] ^= 0xFF  # inside the stored array: zip CRC or digest catches it
        path.write_bytes(bytes(data))
    else:
        path.write_bytes(b"")
    with pytest.raises(CheckpointError):
        read_checkpoint(path)


def test_tampered_array_with_valid_zip_fails_the_digest(tmp_path: Path) -> None:
    path, _ = write_checkpoint(tmp_path, "aibo", {"w": np.arange(4.0)}, {}, meta(1))
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    arrays["model.w"] = arrays["model.w"] + 1
    with open(path, "wb") as f:
        np.savez(f, **arrays)
    with pytest.raises(CheckpointError, match="digest mismatch"):
        read_checkpoint(path)


def test_newer_version_is_refused_and_old_versions_migrate(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    def rewrite_meta(path: Path, **changes: object) -> None:
        with np.load(path, allow_pickle=False) as npz:
            arrays = {k: npz[k] for k in npz.files}
        meta = json.loads(str(arrays["meta"][()]))
        meta.update(changes)
        arrays["meta"] = np.array(json.dumps(meta))
        with open(path, "wb") as f:
            np.savez(f, **arrays)

    path, _ = write_checkpoint(tmp_path, "aibo", {"w": np.arange(2.0)}, {}, meta(1))
    rewrite_meta(path, version=CHECKPOINT_VERSION + 1)
    with pytest.raises(CheckpointError, match="newer than this daemon"):
        read_checkpoint(path)
    rewrite_meta(path, version=0)
    with pytest.raises(CheckpointError, match="no migration"):
        read_checkpoint(path)

    def upgrade(c: ck.Stored) -> ck.Stored:
        return ck.Stored({**c.meta, "version": 1, "migrated": True}, c.model, c.daemon)

    monkeypatch.setitem(ck.MIGRATIONS, 0, upgrade)
    caplog.set_level(logging.WARNING)
    assert read_checkpoint(path).meta.extra["migrated"] is True
    assert "migrating from version 0 to 1" in caplog.text


def test_load_newest_skips_bad_files_with_a_clear_line(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    good, _ = write_checkpoint(tmp_path, "aibo", {"w": np.arange(2.0)}, {}, meta(1))
    wrong, _ = write_checkpoint(tmp_path, "aibo", {"w": np.arange(3.0)}, {}, meta(2))
    bad = tmp_path / "aibo" / "ckpt-00000009.npz"
    bad.write_bytes(b"\x00" * 100)
    (tmp_path / "aibo" / "notes.txt").write_text("ignored")

    def accept(c: ck.Checkpoint) -> None:
        if c.model["w"].shape != (2,):
            raise CheckpointError("wrong shape for this config")

    caplog.set_level(logging.WARNING)
    got = load_newest(tmp_path, "aibo", accept)
    assert got is not None and got.path == good
    assert f"skipping corrupt or unusable checkpoint {bad}: cannot read archive" in caplog.text
    assert f"skipping corrupt or unusable checkpoint {wrong}: wrong shape" in caplog.text
    assert load_newest(tmp_path, "nobody") is None


def test_a_robot_cannot_resume_another_robots_checkpoint(tmp_path: Path) -> None:
    path, _ = write_checkpoint(tmp_path, "aibo", {"w": np.arange(2.0)}, {}, meta(1))
    other = tmp_path / "arm" / path.name
    other.parent.mkdir()
    other.write_bytes(path.read_bytes())
    assert load_newest(tmp_path, "arm") is None


def test_checkpoint_is_a_plain_zip_of_npy_files(tmp_path: Path) -> None:
    path, _ = write_checkpoint(tmp_path, "aibo", model_state(3), DAEMON, meta(3))
    with zipfile.ZipFile(path) as z:
        names = z.namelist()
    assert "meta.npy" in names and "daemon.label_codes.npy" in names
    assert all(n.endswith(".npy") for n in names)
