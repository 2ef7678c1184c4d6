"""CheckpointMeta: one type for every checkpoint's metadata; older formats migrate on read, and a
version-1 checkpoint written by the daemon of that time (tests/data/checkpoints/v1) still loads
and resumes the daemon."""

from __future__ import annotations

import json
import logging
import shutil
from pathlib import Path

import numpy as np
import pytest

from protocols.messages import Dims
from roger_daemon.config import parse_config
from roger_daemon.daemon.checkpoint import (
    CHECKPOINT_VERSION,
    MIGRATIONS,
    CheckpointError,
    CheckpointMeta,
    array_digest,
    read_checkpoint,
    write_checkpoint,
)
from roger_daemon.daemon.checkpoint_meta import Counters, LearnerSpec, MetaError
from roger_daemon.daemon.resume import load_robot
from roger_daemon.daemon.robot_state import RobotState
from roger_daemon.learner.synthetic import subtask_stream

V1 = Path(__file__).parent / "data" / "checkpoints" / "v1"
V1_FILE = V1 / "aibo" / "ckpt-00000001.npz"


def test_the_table_migrates_every_version_before_the_current_one() -> None:
    assert CHECKPOINT_VERSION == 2
    assert sorted(MIGRATIONS) == list(range(1, CHECKPOINT_VERSION))


def test_a_version_1_checkpoint_of_the_daemon_reads_as_the_current_metadata(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.WARNING)
    ck = read_checkpoint(V1_FILE)
    assert "migrating from version 1 to 2" in caplog.text
    m = ck.meta
    assert (m.version, m.robot, m.reason, m.updates, m.x_dim, m.y_dim) == (
        CHECKPOINT_VERSION, "aibo", "shutdown", 20, 23, 9)
    assert (m.daemon, m.session_id, m.session_segment, m.wal_seq) == (
        "roger", "20261202T100000Z-fixture", 0, 20)
    # version 1's top-level model/seed/params are the learner's identity now
    assert (m.learner.kind, m.learner.seed) == ("roger", 0)
    assert m.learner.params is not None and m.learner.params["nu0"] == 24.0
    assert m.counters == Counters(ticks=24, dropped=0, unpaired_actions=0, learn_errors=0,
                                  last_tick=23, last_t=23 / 30, mode="learn+predict",
                                  last_learned_tick=19, invalid={"wrong_dimension": 1})
    assert m.model_digest == array_digest(ck.model) and m.extra == {}
    state = RobotState.from_arrays(ck.daemon)
    assert state.n_learned == 20 and [p.tick for p in state.queue] == [20, 21, 22, 23]
    assert state.newest is not None and state.newest.tick == 23


def test_the_daemon_resumes_from_the_version_1_fixture(tmp_path: Path) -> None:
    shutil.copytree(V1, tmp_path / "ckpt")
    cfg = parse_config({"checkpoint": {"dir": str(tmp_path / "ckpt")},
                        "recording": {"enabled": False}})
    rt, ckpt = load_robot(cfg, cfg.robots[0], fresh=False)
    assert ckpt is not None and ckpt.path == tmp_path / "ckpt" / V1_FILE.relative_to(V1)
    assert (rt.updates, len(rt.queue), rt.ticks, rt.last_learned_tick) == (20, 4, 24, 19)
    assert rt.vocab and dict(rt.invalid) == {"wrong_dimension": 1}
    while rt.queue:  # the model goes on learning where it stopped
        rt.learn_one()
    assert rt.updates == 24 and len(rt.codes) == 24
    # the original file is left as it was: a migration happens in memory only
    assert read_checkpoint(V1_FILE).meta.updates == 20


def test_a_written_checkpoint_reads_back_the_same_metadata(tmp_path: Path) -> None:
    s = subtask_stream(3)
    daemon = RobotState.from_labels(["a", "b", "a"]).to_arrays(Dims(23, 9))
    meta = CheckpointMeta(
        reason="periodic", updates=3, x_dim=23, y_dim=9, created_unix_ns=5, daemon="d1",
        counters=Counters(ticks=4, last_tick=3, last_t=0.1, last_learned_tick=2,
                          invalid={"not_finite": 2}),
        session_id="s", session_segment=1, wal_seq=7,
        learner=LearnerSpec("unimap", 3, {"beta": 10}), recovered_pairs=2,
        recovered_from=("s0",))
    path, written = write_checkpoint(tmp_path, "r1", {"x": s.x}, daemon, meta)
    back = read_checkpoint(path).meta
    assert back == written
    assert (back.robot, back.sequence, back.digest != "") == ("r1", 1, True)
    stored = json.loads(str(np.load(path, allow_pickle=False)["meta"][()]))
    assert stored["learner"] == {"kind": "unimap", "seed": 3, "params": {"beta": 10}}
    assert "model" not in stored and stored["version"] == 2


@pytest.mark.parametrize("key", ["updates", "counters", "learner", "session_id"])
def test_current_metadata_missing_a_field_is_refused_naming_it(tmp_path: Path,
                                                                key: str) -> None:
    path, _ = write_checkpoint(tmp_path, "r", {"w": np.arange(2.0)}, {},
                               CheckpointMeta(reason="t", updates=1, x_dim=1, y_dim=1))
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    meta = json.loads(str(arrays["meta"][()]))
    del meta[key]
    arrays["meta"] = np.array(json.dumps(meta))
    with open(path, "wb") as f:
        np.savez(f, **arrays)
    with pytest.raises(CheckpointError, match=f"metadata: meta lacks {key}"):
        read_checkpoint(path)


def test_mistyped_fields_are_named() -> None:
    good = CheckpointMeta(reason="t", updates=1, x_dim=1, y_dim=1).written("r", 1, "a", "b")
    data = good.to_json()
    assert CheckpointMeta.from_json(data) == good
    with pytest.raises(MetaError, match="updates must be an integer"):
        CheckpointMeta.from_json({**data, "updates": "1"})
    with pytest.raises(MetaError, match="counters.invalid"):
        CheckpointMeta.from_json({**data, "counters": {**data["counters"], "invalid": [1]}})
    with pytest.raises(MetaError, match="learner lacks seed"):
        CheckpointMeta.from_json({**data, "learner": {"kind": "roger", "params": None}})
