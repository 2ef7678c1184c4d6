"""Start-up self-recovery, in process: the daemon's own start-up code (``start_robots``,
``open_recorders``), its service loop on the in-memory transport, real session logs and real
checkpoints. A "crash" copies the log directory as a SIGKILL would leave it (the recorder still
open: no footer, only what was flushed) and starts the next daemon life on the copy.

The real-process crash test is ``test_recovery_integration.py``.
"""

from __future__ import annotations

import logging
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from daemon_sessions import as_version_1, daemon_checkpoint, record_session, synthetic_stream

from protocols import Action, Control, Perception, encode, keys
from roger_daemon.config import DaemonConfig, parse_config
from roger_daemon.daemon.checkpoint import list_checkpoints, read_checkpoint
from roger_daemon.daemon.main import make_model, open_recorders, start_robots
from roger_daemon.daemon.service import Service
from roger_daemon.labels import majority_labels
from roger_daemon.recording import (
    is_complete,
    list_session_files,
    read_timeline,
)
from roger_daemon.recording.startup import CheckpointPosition, plan_recovery
from roger_daemon.replay import replay_session
from roger_daemon.replay.compare import REL_TOL, behaviour, behaviour_differences
from roger_daemon.replay.session import load_checkpoint
from roger_daemon.testing import MemoryTransport

X, Y, LABELS = synthetic_stream("sqrt", 400)
PROBES = [[v] for v in np.linspace(0.0, 1.0, 9)]
TOL = REL_TOL


class FakeClock:
    def __init__(self) -> None:
        self.mono = 1_000_000_000

    def monotonic_ns(self) -> int:
        return self.mono

    def time_ns(self) -> int:
        return 1_795_000_000_000_000_000 + self.mono


def make_cfg(root: Path, logs: Path, *, every: int = 20, wal: bool = False,
             **daemon: Any) -> DaemonConfig:
    """Recovery from the session logs alone (``wal=False``: a deployment without the
    write-ahead log; tests/test_durability.py covers recovery from the write-ahead log)."""
    return parse_config({
        "daemon": {"clock": "lockstep", "seed": 3, **daemon},
        "robots": [{"id": "sim", "x_dim": 1, "y_dim": 1}],
        "checkpoint": {"dir": str(root / "ckpt"), "every_updates": every, "every_s": 0,
                       "wal": wal},
        "recording": {"enabled": True, "dir": str(logs)},
    })


class Life:
    """One daemon life: start-up (with recovery), then the loop on a memory transport."""

    def __init__(self, cfg: DaemonConfig, *, fresh: bool = False) -> None:
        self.cfg = cfg
        robots, where = start_robots(cfg, fresh=fresh)
        self.rt, self.where = robots["sim"], where["sim"]
        self.recorders = open_recorders(cfg, robots, where)
        self.clock = FakeClock()
        self.transport = MemoryTransport(now_ns=self.clock.monotonic_ns)
        self.service = Service(
            cfg, self.transport, robots, clock=self.clock, sync_checkpoints=True,
            recorders=self.recorders, resumed={"sim": self.where.checkpoint},
        )
        self.service.start()

    def send(self, kind: str, msg: Any) -> None:
        assert self.transport.inject(keys.key("sim", kind), encode(msg)) >= 1

    def pairs(self, ticks: range, *, settle: bool = True) -> None:
        for t in ticks:
            self.send("perception", Perception("sim", t, t / 30, x=X[t]))
            self.send("action", Action("sim", t, t / 30, y=Y[t], label=LABELS[t]))
            if settle:
                self.settle()

    def settle(self) -> None:
        for _ in range(1000):
            self.service.step(0)
            if not self.rt.queue and not len(self.service.inbox):
                return
        raise AssertionError("the loop did not settle")

    def flush(self) -> None:
        rec = self.recorders["sim"]
        rec.flush()  # type: ignore[attr-defined]

    def crash(self, to: Path) -> Path:
        """What a SIGKILL leaves: copy the logs as they are on disk now (no footer)."""
        src = self.cfg.recording.dir
        shutil.copytree(src, to)
        return to

    def stop(self) -> None:
        self.service.shutdown()


def reference(ticks: list[int], *, seed: int = 3) -> Any:
    cfg = make_cfg(Path("/nonexistent"), Path("/nonexistent"))
    robot = cfg.robots[0]
    assert robot.seed == seed
    m = make_model(robot)
    for t in ticks:
        m.learn_one(X[t], Y[t])
    return m


def assert_same(model: Any, ref: Any) -> None:
    diffs = behaviour_differences(behaviour(model, PROBES), behaviour(ref, PROBES), TOL)
    assert diffs == []


def test_crash_after_a_checkpoint_relearns_the_log_tail(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO)
    a = Life(make_cfg(tmp_path, tmp_path / "logs1"))
    a.pairs(range(50))  # checkpoints at 20 and 40
    a.flush()
    logs2 = a.crash(tmp_path / "logs2")
    (first,) = list_session_files(logs2)
    assert not is_complete(first.path)
    assert read_checkpoint(list_checkpoints(tmp_path / "ckpt", "sim")[0]).meta.updates == 40

    b = Life(make_cfg(tmp_path, logs2))
    assert b.rt.updates == 50 and b.rt.recovered_pairs == 10 and b.rt.last_learned_tick == 49
    assert_same(b.rt.model, reference(list(range(50))))
    labels = majority_labels(b.rt.model.assignments(), [LABELS[t] for t in range(50)])
    assert b.rt.expert_labels() == labels  # the label of every re-learned pair came back too
    assert is_complete(first.path) and (logs2 / (first.path.name + ".damaged")).exists()
    assert "recovered in place" in caplog.text
    assert "re-learned 10 pairs (ticks 40..49)" in caplog.text
    ck = read_checkpoint(list_checkpoints(tmp_path / "ckpt", "sim")[0])
    assert ck.meta.reason == "recovered" and ck.meta.updates == 50
    assert ck.meta.session_id == first.session_id and ck.meta.session_segment == 0
    assert ck.meta.counters.last_learned_tick == 49
    assert b.where.checkpoint == str(ck.path) and b.where.recovered_pairs == 10

    # the second life goes on, crashes again before its next checkpoint: recovered again
    b.pairs(range(50, 65))
    b.flush()
    logs3 = b.crash(tmp_path / "logs3")
    c = Life(make_cfg(tmp_path, logs3))
    assert c.rt.updates == 65 and c.rt.recovered_pairs == 15
    assert_same(c.rt.model, reference(list(range(65))))
    c.pairs(range(65, 80))
    c.stop()
    final = read_checkpoint(list_checkpoints(tmp_path / "ckpt", "sim")[0])
    model, _, _ = load_checkpoint(final.path)  # type: ignore[arg-type]
    assert_same(model, reference(list(range(80))))

    # the session that resumed from the recovered checkpoint replays exactly from it
    b_id = b.recorders["sim"].session_id  # type: ignore[attr-defined]
    second = [sf for sf in list_session_files(logs3) if sf.session_id == b_id]
    assert len(second) == 1
    init, queued, _ = load_checkpoint(ck.path)  # type: ignore[arg-type]
    res = replay_session(second[0].path, initial_model=init, initial_pairs=queued)
    assert res.ok(TOL) and res.n_learned == 65 and len(res.diffs) == 15


def test_a_checkpoint_newer_than_the_log_is_kept(tmp_path: Path,
                                                 caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO)
    a = Life(make_cfg(tmp_path, tmp_path / "logs1"))
    a.pairs(range(30))
    a.flush()  # the log holds 30 pairs ...
    a.pairs(range(30, 45))  # ... the checkpoint 40 (the last 15 pairs never reached the disk)
    b = Life(make_cfg(tmp_path, a.crash(tmp_path / "logs2")))
    assert b.rt.updates == 40 and b.rt.recovered_pairs == 0
    assert "the checkpoint is newer than the logs" in caplog.text
    assert_same(b.rt.model, reference(list(range(40))))


def test_queued_pairs_of_the_checkpoint_come_before_the_tail(tmp_path: Path) -> None:
    a = Life(make_cfg(tmp_path, tmp_path / "logs1", every=0, mode="learn"))
    a.pairs(range(12))
    a.pairs(range(12, 20), settle=False)
    a.service.step(0)  # drains all 16 messages, learns one pair: 7 stay queued
    assert a.rt.updates == 13 and len(a.rt.queue) == 7
    a.send("control", Control("sim", 0, 0.0, op="checkpoint"))
    a.service.step(0)
    assert read_checkpoint(list_checkpoints(tmp_path / "ckpt", "sim")[0]).daemon[
        "queue_ticks"].size >= 5
    a.settle()
    a.pairs(range(20, 30))
    a.flush()
    b = Life(make_cfg(tmp_path, a.crash(tmp_path / "logs2"), every=0, mode="learn"))
    assert b.rt.updates == 30 and not b.rt.queue
    assert_same(b.rt.model, reference(list(range(30))))


def test_dropped_pairs_are_named_in_the_log_so_replay_and_recovery_stay_exact(
    tmp_path: Path
) -> None:
    a = Life(make_cfg(tmp_path, tmp_path / "logs1", every=0, mode="learn", queue_size=4))
    a.pairs(range(10))
    a.pairs(range(10, 20), settle=False)  # 10 pairs at once into a queue of 4
    a.service.step(0)
    a.settle()
    dropped = a.rt.dropped
    assert dropped >= 5
    a.pairs(range(20, 30))
    learned_ticks = list(range(10)) + [t for t in range(10, 20)][: 10 - dropped] + list(
        range(20, 30))
    a.flush()
    logs2 = a.crash(tmp_path / "logs2")
    (sf,) = list_session_files(logs2)
    tl = read_timeline([sf.path])
    assert tl.dropped_recorded == dropped and tl.unexplained_drops == 0
    assert [p.tick for p in tl.pairs] == learned_ticks
    assert_same(a.rt.model, reference(learned_ticks))
    # no checkpoint at all (every=0): the crashed fresh session is re-learned from scratch
    b = Life(make_cfg(tmp_path, logs2, every=0, mode="learn", queue_size=4))
    assert b.rt.recovered_pairs == len(learned_ticks)
    assert_same(b.rt.model, reference(learned_ticks))


def test_reset_after_the_checkpoint_restarts_from_a_fresh_model(tmp_path: Path) -> None:
    a = Life(make_cfg(tmp_path, tmp_path / "logs1"))
    a.pairs(range(25))  # checkpoint at 20
    a.send("control", Control("sim", 0, 0.0, op="reset"))
    a.pairs(range(100, 112))
    a.flush()
    b = Life(make_cfg(tmp_path, a.crash(tmp_path / "logs2")))
    assert b.rt.updates == 12 and b.rt.recovered_pairs == 12
    assert_same(b.rt.model, reference(list(range(100, 112))))
    ck = read_checkpoint(list_checkpoints(tmp_path / "ckpt", "sim")[0])
    assert ck.meta.reason == "recovered" and ck.meta.session_segment == 1


def test_fresh_ignores_checkpoint_and_logs(tmp_path: Path) -> None:
    a = Life(make_cfg(tmp_path, tmp_path / "logs1"))
    a.pairs(range(30))
    a.flush()
    logs2 = a.crash(tmp_path / "logs2")
    b = Life(make_cfg(tmp_path, logs2), fresh=True)
    assert b.rt.updates == 0 and b.rt.recovered_pairs == 0
    old = [sf for sf in list_session_files(logs2) if sf.session_id != b.recorders[
        "sim"].session_id]  # type: ignore[attr-defined]
    assert len(old) == 1 and not is_complete(old[0].path)  # not even repaired


def test_no_checkpoint_and_a_clean_log_leaves_the_model_fresh(tmp_path: Path) -> None:
    a = Life(make_cfg(tmp_path, tmp_path / "logs", every=0))
    a.pairs(range(10))
    a.recorders["sim"].close()
    shutil.rmtree(tmp_path / "ckpt", ignore_errors=True)
    b = Life(make_cfg(tmp_path, tmp_path / "logs", every=0))
    assert b.rt.updates == 0  # an old, finished session is not resurrected


# -- bad logs: reported, skipped, never fatal ----------------------------------------------


def test_corrupt_and_foreign_logs_are_reported_and_skipped(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO)
    a = Life(make_cfg(tmp_path, tmp_path / "logs1"))
    a.pairs(range(30))  # checkpoint at 20
    a.flush()
    logs2 = a.crash(tmp_path / "logs2")
    (sf,) = list_session_files(logs2)
    garbage = logs2 / "roger-sim-20000101T000000Z.mcap"  # sorts first: an old, broken file
    garbage.write_bytes(b"\x00" * 100)
    other = logs2 / "roger-other-20000101T000000Z.mcap"  # another robot's log
    other.write_bytes(b"not mcap")
    (logs2 / "notes.txt").write_text("not a log")
    b = Life(make_cfg(tmp_path, logs2))
    assert b.rt.updates == 30 and b.rt.recovered_pairs == 10
    assert f"log {garbage} is not usable" in caplog.text
    assert other.exists()  # other robots' logs are not touched

    # a checkpoint that does not belong to this log: ticks differ -> logs not used
    plan = plan_recovery(logs2, "sim", dims=b.rt.dims, checkpoint=CheckpointPosition(
        learned=20, session_id=sf.session_id, last_tick=7))
    assert not plan.newer and any("do not continue the checkpoint" in n for n in plan.notes)
    # a checkpoint whose session is unknown and which no log resumed from -> nothing
    plan = plan_recovery(logs2, "sim", dims=b.rt.dims,
                         checkpoint=CheckpointPosition(learned=20, path="/elsewhere.npz"))
    assert not plan.newer and "does not name its session" in plan.summary


def test_a_session_of_another_history_ends_the_walk(tmp_path: Path) -> None:
    """Session B claims to continue a checkpoint of a session that is not in this history."""
    logs = tmp_path / "logs"
    a = record_session(logs, n_ticks=40, checkpoint_at=(20,), close=False,
                       checkpoint_dir=tmp_path / "ck-a")
    daemon_checkpoint(tmp_path / "ck-b", "sim", a.checkpoints[20], dims=a.dims,
                      labels=[p[3] for p in a.pairs[:20]],
                      session_id="roger-sim-19990101T000000Z", segment=0)
    b = record_session(logs, n_ticks=10, tick0=300, checkpoint_dir=tmp_path / "ck-b")
    assert b.recorder.session_id > a.recorder.session_id  # type: ignore[union-attr]
    sid = a.recorder.session_id  # type: ignore[union-attr]
    a.recorder.flush()  # type: ignore[union-attr]
    plan = plan_recovery(logs, "sim", dims=b.dims, checkpoint=CheckpointPosition(
        learned=20, session_id=sid, last_tick=19))
    assert [p.tick for p in plan.pairs] == list(range(20, 40))  # A's tail only
    assert any("another history" in n for n in plan.notes)


def test_a_log_with_other_dimensions_is_skipped(tmp_path: Path) -> None:
    logs = tmp_path / "logs"
    a = record_session(logs, n_ticks=30, close=False)
    a.recorder.flush()  # type: ignore[union-attr]
    from protocols.messages import Dims

    plan = plan_recovery(logs, "sim", dims=Dims(23, 9), checkpoint=None)
    assert not plan.newer and any("dimensions 1/1" in n for n in plan.notes)


def test_recovery_never_raises(tmp_path: Path, caplog: pytest.LogCaptureFixture,
                               monkeypatch: pytest.MonkeyPatch) -> None:
    a = Life(make_cfg(tmp_path, tmp_path / "logs1"))
    a.pairs(range(30))
    a.flush()
    logs2 = a.crash(tmp_path / "logs2")
    logs3 = a.crash(tmp_path / "logs3")
    import roger_daemon.recording.startup as startup

    def boom(*args: Any, **kwargs: Any) -> None:
        raise RuntimeError("something unexpected")

    monkeypatch.setattr(startup, "_plan", boom)
    caplog.set_level(logging.WARNING)
    b = Life(make_cfg(tmp_path, logs2))
    assert b.rt.updates == 20  # the checkpoint alone
    assert "reading the logs failed (RuntimeError: something unexpected)" in caplog.text

    # a learner that fails while re-learning: the checkpoint is loaded again, untouched
    monkeypatch.undo()
    import roger_daemon.daemon.robot as robot_mod

    def bad_learn(self: Any) -> float:
        raise MemoryError("no memory")

    monkeypatch.setattr(robot_mod.RobotRuntime, "learn_one", bad_learn)
    c_robots, _ = start_robots(make_cfg(tmp_path, logs3), fresh=False)
    assert c_robots["sim"].updates == 20 and not c_robots["sim"].queue
    assert "start-up recovery failed while re-learning" in caplog.text


def test_recovery_by_hand_with_log_recover_and_replay_checkpoint(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The README procedure: ``roger log recover --in-place``, then ``roger replay
    --checkpoint <last checkpoint> --save-checkpoint <dir>``; the daemon resumes from that."""
    from roger_daemon.cli import main as roger

    a = Life(make_cfg(tmp_path, tmp_path / "logs1"))
    a.pairs(range(50))  # checkpoints at 20 and 40
    a.flush()
    logs2 = a.crash(tmp_path / "logs2")
    (sf,) = list_session_files(logs2)
    last = list_checkpoints(tmp_path / "ckpt", "sim")[0]
    assert read_checkpoint(last).meta.updates == 40
    assert roger(["log", "recover", str(sf.path), "--in-place"]) == 3  # lossy: no footer
    assert is_complete(sf.path)
    capsys.readouterr()
    assert roger(["replay", str(sf.path), "--checkpoint", str(last), "--check", "--no-progress",
                  "--save-checkpoint", str(tmp_path / "ckpt")]) == 0
    out = capsys.readouterr().out
    assert "learned:      10 pairs" in out and "checkpoint:   " in out and "result:       OK" in out
    assert "result:       OK, bit-identical" in out  # the recorded checkpoint digest too
    saved = read_checkpoint(list_checkpoints(tmp_path / "ckpt", "sim")[0])
    assert saved.meta.reason == "replay" and saved.meta.updates == 50

    b = Life(make_cfg(tmp_path, logs2))  # resumes from the replayed checkpoint: nothing newer
    assert b.where.checkpoint == str(saved.path) and b.rt.recovered_pairs == 0
    assert b.rt.updates == 50 and b.rt.last_learned_tick == 49
    assert_same(b.rt.model, reference(list(range(50))))
    labels = majority_labels(b.rt.model.assignments(), [LABELS[t] for t in range(50)])
    assert b.rt.expert_labels() == labels


def test_a_session_that_started_with_queued_pairs_is_continued_exactly(tmp_path: Path) -> None:
    """Life 1 is killed with pairs still queued (saved in its checkpoint, already logged);
    life 2 learns them first (metadata ``restored_queued_pairs``), learns more, is killed
    before any checkpoint; life 3 rebuilds checkpoint + queue + life 2's pairs."""
    cfg1 = make_cfg(tmp_path, tmp_path / "logs1", every=0, mode="learn")
    a = Life(cfg1)
    a.pairs(range(12))
    a.pairs(range(12, 20), settle=False)
    a.send("control", Control("sim", 0, 0.0, op="checkpoint"))
    a.service.step(0)  # 8 pairs formed, the checkpoint (12 learned + 8 queued), 1 learned
    ck = read_checkpoint(list_checkpoints(tmp_path / "ckpt", "sim")[0])
    assert ck.meta.updates == 12 and ck.daemon["queue_ticks"].tolist() == list(range(12, 20))
    a.flush()
    b = Life(make_cfg(tmp_path, a.crash(tmp_path / "logs2"), every=0, mode="learn"))
    assert b.rt.recovered_pairs == 0 and len(b.rt.queue) == 8  # the log ends with the queue
    b.settle()
    b.pairs(range(20, 25))
    b.flush()
    logs3 = b.crash(tmp_path / "logs3")
    b_id = b.recorders["sim"].session_id  # type: ignore[attr-defined]
    (b_file,) = [sf.path for sf in list_session_files(logs3) if sf.session_id == b_id]
    tl = read_timeline([b_file])  # the decision records name the queued pairs it learned
    assert tl.segments[0].queued == 0 and [p.index for p in tl.pairs] == list(range(12, 25))
    tl = read_timeline([as_version_1(b_file, tmp_path / "b-v1.mcap")])  # an older daemon's log
    assert tl.segments[0].queued == 8 and [p.index for p in tl.pairs] == list(range(20, 25))
    c = Life(make_cfg(tmp_path, logs3, every=0, mode="learn"))
    assert c.rt.updates == 25 and c.rt.recovered_pairs == 5
    assert_same(c.rt.model, reference(list(range(25))))


def test_a_daemon_without_the_write_ahead_log_says_what_it_gives_up(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """``checkpoint.wal = false`` stays (docs/durability.md, *Without the log*), but a start
    says once that acknowledged pairs can be lost; the default start says nothing of it."""
    with caplog.at_level(logging.WARNING, logger="roger_daemon.daemon.resume"):
        start_robots(make_cfg(tmp_path / "a", tmp_path / "a" / "logs", wal=True), fresh=False)
    assert "checkpoint.wal = false" not in caplog.text
    with caplog.at_level(logging.WARNING, logger="roger_daemon.daemon.resume"):
        start_robots(make_cfg(tmp_path / "b", tmp_path / "b" / "logs"), fresh=False)
    assert caplog.text.count("checkpoint.wal = false: a crash can lose acknowledged") == 1
