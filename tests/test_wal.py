"""The write-ahead log on real files: records round-trip, a torn or garbled tail ends the
segment, segments are pruned whole, and replay re-learns exactly what was logged."""

from __future__ import annotations

import time
from collections.abc import Callable
from concurrent.futures import Executor, Future
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from protocols.messages import Dims
from roger_daemon.config import parse_config
from roger_daemon.daemon.checkpoint import array_digest, list_checkpoints, read_checkpoint
from roger_daemon.daemon.main import make_model
from roger_daemon.daemon.robot import Pair, RobotRuntime
from roger_daemon.daemon.wal import WriteAheadLog, read_records, replay_into, segments


def _pair(i: int) -> tuple[np.ndarray, np.ndarray]:
    return np.array([i / 10.0]), np.array([np.sqrt(i / 10.0)])


def test_records_round_trip_and_survive_without_commit(tmp_path: Path) -> None:
    w = WriteAheadLog(tmp_path, 0)
    w.append_fresh()
    for i in range(3):
        x, y = _pair(i)
        w.append_pair(i, 100 + i, x, y, "seek")
    assert w.dirty and w.durable_seq == -1
    # not committed, not closed: what a kill -9 leaves; the OS has the bytes
    recs = read_records(tmp_path)
    assert [r.kind for r in recs] == ["fresh", "pair", "pair", "pair"]
    assert [r.seq for r in recs] == [0, 1, 2, 3]
    assert recs[3].index == 2 and recs[3].tick == 102 and recs[3].label == "seek"
    assert np.array_equal(recs[3].x, _pair(2)[0]) and np.array_equal(recs[3].y, _pair(2)[1])
    w.commit()
    assert w.durable_seq == 3 and not w.dirty and w.commits == 1
    w.close()


class _Later(Executor):
    """An executor that runs what it is given only when told to (a background commit that
    is still running while the loop appends)."""

    def __init__(self) -> None:
        self.jobs: list[tuple[Future[None], Callable[..., None], tuple[Any, ...]]] = []

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future[Any]:
        job: Future[None] = Future()
        self.jobs.append((job, fn, args))
        return job

    def run_all(self) -> None:
        for job, fn, args in self.jobs:
            try:
                fn(*args)
                job.set_result(None)
            except OSError as exc:
                job.set_exception(exc)
        self.jobs.clear()


def test_an_early_commit_makes_what_was_appended_before_it_durable(tmp_path: Path) -> None:
    w = WriteAheadLog(tmp_path, 0)
    pool = _Later()
    for i in range(2):
        w.append_pair(i, i, *_pair(i), "seek")
    w.commit_early(0, 10**9, pool)  # not due: started in the background
    w.commit_early(0, 10**9, pool)  # one at a time
    assert len(pool.jobs) == 1 and w.dirty and w.durable_seq == -1
    w.append_pair(2, 2, *_pair(2), "seek")  # appended while that commit runs
    synced: list[int] = []
    sync = w._sync
    w._sync = lambda target: (synced.append(target), sync(target))  # type: ignore[method-assign]
    pool.run_all()
    # the background commit chased the third record with a second fdatasync of its own
    assert synced == [1, 2] and w.durable_seq == 2 and not w.dirty and w.commits == 2
    w.commit_early(0, 10**9, pool)
    assert not pool.jobs  # nothing left to commit
    w.append_pair(3, 3, *_pair(3), "seek")
    w.commit_early(2 * 10**9 + time.monotonic_ns(), 10**9, pool)  # due: committed now
    assert not pool.jobs and w.durable_seq == 3 and not w.dirty
    w.close()


def test_a_failed_early_commit_stops_the_next_commit(tmp_path: Path) -> None:
    w = WriteAheadLog(tmp_path, 0)
    pool = _Later()
    w.append_pair(0, 0, *_pair(0), "seek")
    w.commit_early(0, 10**9, pool)
    fd = w._fd
    w._fd = 999_999  # the disk goes away under the background commit: EBADF
    pool.run_all()
    w._fd = fd
    assert w.dirty and w.durable_seq == -1
    with pytest.raises(OSError):
        w.commit()
    w.close()
    assert [r.seq for r in read_records(tmp_path)] == [0]


def test_a_torn_tail_ends_the_segment(tmp_path: Path) -> None:
    w = WriteAheadLog(tmp_path, 0)
    for i in range(4):
        w.append_pair(i, i, *_pair(i), "")
    w.close()
    (_, path), = segments(tmp_path)
    data = bytearray(path.read_bytes())
    end = data.rstrip(b"\0")
    data[len(end) - 3] ^= 0xFF  # a garbled byte in the last record
    path.write_bytes(bytes(data))
    assert [r.index for r in read_records(tmp_path)] == [0, 1, 2]
    # the next life starts a new segment after the last readable record
    w2 = WriteAheadLog(tmp_path, 3)
    w2.append_pair(3, 3, *_pair(3), "")
    w2.close()
    assert [r.index for r in read_records(tmp_path)] == [0, 1, 2, 3]


def test_segments_grow_past_the_preallocation_and_prune_whole(tmp_path: Path) -> None:
    w = WriteAheadLog(tmp_path, 0)
    big = np.zeros(4000)  # ~32 kB per record: the 1 MiB preallocation is outgrown
    for i in range(40):
        w.append_pair(i, i, big, big, "")
    w.rotate()
    w.append_pair(40, 40, *_pair(1), "")
    w.close()
    assert [first for first, _ in segments(tmp_path)] == [0, 40]
    assert len(read_records(tmp_path)) == 41
    w3 = WriteAheadLog(tmp_path, 41)
    assert w3.prune(39) == 1  # the first segment (records 0..39) is covered
    assert [first for first, _ in segments(tmp_path)] == [40, 41]
    w3.close()


def test_replay_relearns_in_order_across_a_gap_and_stops_behind_the_model(tmp_path: Path) -> None:
    cfg = parse_config({"robots": [{"id": "sim", "x_dim": 1, "y_dim": 1}]})
    robot = cfg.robots[0]

    def runtime() -> RobotRuntime:
        return RobotRuntime("sim", Dims(1, 1), make_model(robot), lambda: make_model(robot))

    live = runtime()
    live.wal = WriteAheadLog(tmp_path, 0)
    live.wal.append_fresh()
    for i in range(12):
        x, y = _pair(i)
        live.queue.append(Pair(x, y, live._label_code("a"), i))
        live.learn_one()
    live.wal.close()
    again = runtime()
    rep = replay_into(again, tmp_path, -1)
    assert rep.pairs == 12 and rep.fresh == 1 and rep.stopped == "" and rep.next_seq == 13
    assert again.updates == 12 and again.last_learned_tick == 11
    ref = make_model(robot)
    for i in range(12):
        ref.learn_one(*_pair(i))
    assert array_digest(again.model.state_dict()) == array_digest(ref.state_dict())
    # a checkpoint at 5 pairs, then a replay that starts after it
    partial = runtime()
    for i in range(5):
        partial.model.learn_one(*_pair(i))
    assert replay_into(partial, tmp_path, after_seq=5).pairs == 7
    # pairs the log lacks (its segments pruned after a checkpoint found unreadable) and no
    # copy holds: counted lost and named, and every record after them is still learned
    behind = runtime()
    rep = replay_into(behind, tmp_path, after_seq=3)
    assert rep.pairs == 9 and rep.lost == 3 and rep.stopped == ""
    assert rep.notes == ["pairs 0..2 (before record 4, tick 3) are lost: no intact copy"]
    assert behind.updates == 9
    # a model ahead of what the log continues: the replay stops and says why
    ahead = runtime()
    for i in range(8):
        ahead.model.learn_one(*_pair(i))
    rep = replay_into(ahead, tmp_path, after_seq=3)
    assert rep.pairs == 0 and "gap" in rep.stopped


def test_a_session_after_a_wal_recovery_replays_exactly(tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    """Life 1 learns 50 pairs (checkpoint at 40) and dies; life 2 re-learns 10 from the log,
    names the recovered checkpoint as its start, learns 15 more; its session replays from
    that checkpoint with every prediction reproduced."""
    from test_recovery import Life, assert_same, make_cfg, reference

    from roger_daemon.cli import main as roger
    from roger_daemon.recording import list_session_files
    from roger_daemon.recording.mcapio import read_metadata

    a = Life(make_cfg(tmp_path, tmp_path / "logs1", wal=True))
    a.pairs(range(50))
    a.flush()
    logs2 = a.crash(tmp_path / "logs2")  # the WAL is where a kill leaves it: not closed
    b = Life(make_cfg(tmp_path, logs2, wal=True))
    assert b.rt.updates == 50 and b.rt.recovered_pairs == 10
    ck = read_checkpoint(list_checkpoints(tmp_path / "ckpt", "sim")[0])
    assert ck.meta.reason == "recovered" and b.where.checkpoint == str(ck.path)
    assert_same(b.rt.model, reference(list(range(50))))
    b.pairs(range(50, 65))
    b.stop()
    session = [sf.path for sf in list_session_files(logs2)][-1]
    assert read_metadata(session)["checkpoint"] == str(ck.path)
    capsys.readouterr()
    assert roger(["replay", str(session), "--checkpoint", str(ck.path), "--check",
                  "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "learned:      15 pairs" in out and "result:       OK" in out


def test_pairs_queued_in_the_checkpoint_are_not_learned_twice(tmp_path: Path) -> None:
    """The checkpoint is taken while 10 pairs wait in the queue; they are learned (and
    logged) after it. Recovery re-learns them from the log and takes them off the restored
    queue, so each is learned once."""
    from test_recovery import Life, assert_same, make_cfg, reference

    from protocols import Control

    # mode "learn": no perception is answered, so nothing learns the queue during the drain
    a = Life(make_cfg(tmp_path, tmp_path / "logs", every=0, wal=True, mode="learn"))
    a.pairs(range(10), settle=False)
    a.send("control", Control("sim", 0, 0.0, op="checkpoint"))
    a.settle()  # one drain: pairs queued, checkpoint (with the queue), then learning
    ck = read_checkpoint(list_checkpoints(tmp_path / "ckpt", "sim")[0])
    assert ck.meta.updates == 0 and len(ck.daemon["queue_ticks"]) == 10
    assert a.rt.updates == 10
    b = Life(make_cfg(tmp_path, tmp_path / "logs", every=0, wal=True))  # a's kill -9
    assert b.rt.updates == 10 and len(b.rt.queue) == 0 and b.rt.recovered_pairs == 10
    assert_same(b.rt.model, reference(list(range(10))))


def test_a_reset_after_the_checkpoint_is_replayed(tmp_path: Path) -> None:
    from test_recovery import Life, assert_same, make_cfg, reference

    from protocols import Control

    a = Life(make_cfg(tmp_path, tmp_path / "logs", every=0, wal=True))
    a.pairs(range(10))
    a.send("control", Control("sim", 0, 0.0, op="checkpoint"))
    a.settle()
    a.pairs(range(10, 15))
    a.send("control", Control("sim", 0, 0.0, op="reset"))
    a.settle()
    a.pairs(range(15, 21))
    assert read_checkpoint(list_checkpoints(tmp_path / "ckpt", "sim")[0]).meta.updates == 10
    b = Life(make_cfg(tmp_path, tmp_path / "logs", every=0, wal=True))  # a's kill -9
    assert b.rt.updates == 6 and b.rt.recovered_pairs == 11  # 5, the reset, then 6
    assert_same(b.rt.model, reference(list(range(15, 21))))


def test_a_pair_re_sent_after_a_recovery_checkpoint_is_not_learned_twice(
        tmp_path: Path) -> None:
    """The rare sequence of the 20-kill durability test, made deterministic: life a learns
    pairs 0-9 (logged) and dies before answering pair 9; life b re-learns them from the log,
    writes its recovery checkpoint, recognises the re-sent pair 9 and dies before answering
    it; life c resumes from that checkpoint, after which the log holds nothing, and gets
    pair 9 a third time. The checkpoint carries the newest pair received, so c recognises it
    too (before 2026-11-26 it learned it a second time: 11 updates for 10 pairs)."""
    from test_recovery import Life, assert_same, make_cfg, reference

    def life() -> Life:
        return Life(make_cfg(tmp_path, tmp_path / "logs", every=0, wal=True))

    a = life()
    a.pairs(range(10))
    assert a.rt.updates == 10
    b = life()  # a's kill -9
    assert b.rt.updates == 10 and b.rt.recovered_pairs == 10
    assert list_checkpoints(tmp_path / "ckpt", "sim")  # the recovery checkpoint
    b.pairs(range(9, 10))  # the sender re-sends the tick it got no answer for
    assert b.rt.updates == 10 and b.rt.resent == 1
    c = life()  # b's kill -9, before its answer
    assert c.rt.updates == 10 and c.rt.recovered_pairs == 0
    c.pairs(range(9, 10))
    assert c.rt.updates == 10 and c.rt.resent == 1
    assert_same(c.rt.model, reference(list(range(10))))


def test_an_appends_age_is_judged_on_the_daemons_clock(tmp_path: Path) -> None:
    """The daemon passes its loop's ``now`` to ``commit_early``; the log dates its appends on
    the same clock (the service sets it at start), so an append is due for a synchronous
    commit after ``wal_commit_ms`` of that clock, a test's fake clock included."""
    from test_daemon_service import Harness, make_config

    wal = WriteAheadLog(tmp_path / "wal", 0)
    clock = Harness(make_config(tmp_path), wal=wal).clock
    wal.append_pair(0, 0, *_pair(0), "seek")
    assert wal.dirty and not wal.due(clock.monotonic_ns(), 10**6)
    clock.advance(0.002)
    assert wal.due(clock.monotonic_ns(), 10**6)
    wal.close()


def test_a_smaller_reserve_stops_learning_on_a_full_disk_below_its_quarter(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``checkpoint.wal_reserve_kb`` (here 64 kB): the segment is zero-filled that much at a
    time; once it cannot grow (ENOSPC) the log learns on its reserve and stops accepting
    while less than a quarter of it (16 kB) is left, then resumes when space is back."""
    import errno
    import os

    from roger_daemon.daemon import wal as wal_mod

    w = WriteAheadLog(tmp_path, 0, preallocate=64 << 10)
    assert w.reserve == 64 << 10 and w.low_water == 16 << 10
    real = wal_mod._zero_fill

    def disk_full(fd: int, start: int, size: int) -> int:
        raise wal_mod._Partial(OSError(errno.ENOSPC, os.strerror(errno.ENOSPC)), start)

    monkeypatch.setattr(wal_mod, "_zero_fill", disk_full)
    big = np.zeros(500)  # ~8 kB a record
    appended = 0
    while w.accepting:
        w.append_pair(appended, appended, big, big, "")
        appended += 1
    assert w.full and w.reserve < 16 << 10
    assert 4 <= appended <= 7  # 64 kB less a quarter, 8 kB at a time: nowhere near 1 MiB's
    monkeypatch.setattr(wal_mod, "_zero_fill", real)
    assert w.poll_space(w.clock() + wal_mod.RETRY_NS)
    assert w.accepting and not w.full and w.reserve >= 64 << 10
    w.close()
    assert len(read_records(tmp_path)) == appended
