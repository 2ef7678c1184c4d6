"""The service loop with the in-memory transport, a fake clock and the real learner."""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest

from protocols import Action, Control, Perception, Status, decode, encode, keys
from protocols.messages import MAX_PAYLOAD_BYTES, Prediction
from roger_daemon.config import DaemonConfig, parse_config
from roger_daemon.daemon.checkpoint import array_digest, list_checkpoints, read_checkpoint
from roger_daemon.daemon.main import build_robot
from roger_daemon.daemon.service import Service
from roger_daemon.daemon.wal import WriteAheadLog
from roger_daemon.labels import majority_labels_coded as majority_labels
from roger_daemon.learner.synthetic import subtask_stream
from roger_daemon.testing import MemoryTransport

LABELS = ("seek", "trap", "aim", "kick")
STREAM = subtask_stream(120)


class FakeClock:
    def __init__(self) -> None:
        self.mono = 1_000_000_000
        self.wall = 1_700_000_000_000_000_000

    def monotonic_ns(self) -> int:
        return self.mono

    def time_ns(self) -> int:
        return self.wall + self.mono

    def advance(self, seconds: float) -> None:
        self.mono += round(seconds * 1e9)


class FakeRecorder:
    def __init__(self) -> None:
        self.writes: list[tuple[str, bytes, int, int, int]] = []
        self.polls = 0
        self.closed = False

    def write(self, key: str, payload: bytes, *, log_time_ns: int, publish_time_ns: int,
              sequence: int) -> None:
        self.writes.append((key, payload, log_time_ns, publish_time_ns, sequence))

    def poll(self, now_ns: int) -> None:
        self.polls += 1

    def close(self) -> None:
        self.closed = True


def make_config(tmp_path: Path, checkpoint: dict[str, Any] | None = None,
                **daemon: Any) -> DaemonConfig:
    raw: dict[str, Any] = {
        "daemon": {"clock": "lockstep", **daemon},
        "robots": [{"id": "aibo"}],
        "checkpoint": {"dir": str(tmp_path / "ckpt"), "every_updates": 0, "every_s": 0,
                       **(checkpoint or {})},
        "recording": {"enabled": False},
    }
    return parse_config(raw)


class Harness:
    def __init__(self, cfg: DaemonConfig, *, fresh: bool = True,
                 recorder: FakeRecorder | None = None, wal: WriteAheadLog | None = None) -> None:
        self.clock = FakeClock()
        self.transport = MemoryTransport(now_ns=self.clock.monotonic_ns)
        rt, resumed = build_robot(cfg, cfg.robots[0], fresh=fresh)
        if wal is not None:  # attached before start, as the daemon does
            rt.wal = wal
        self.rt = rt
        self.service = Service(
            cfg, self.transport, {"aibo": rt}, clock=self.clock, sync_checkpoints=True,
            recorders={"aibo": recorder} if recorder else None, resumed={"aibo": resumed},
        )
        self.service.start()

    def send(self, kind: str, payload: bytes, robot: str = "aibo") -> None:
        assert self.transport.inject(keys.key(robot, kind), payload) >= 1

    def pair(self, t: int, *, action_first: bool = False) -> None:
        p = encode(Perception("aibo", t, t / 30, x=STREAM.x[t]))
        a = encode(Action("aibo", t, t / 30, y=STREAM.y[t], label=LABELS[STREAM.labels[t]]))
        for kind, data in (("action", a), ("perception", p)) if action_first else (
            ("perception", p), ("action", a)
        ):
            self.send(kind, data)

    def settle(self, cycles: int = 200) -> None:
        for _ in range(cycles):
            self.service.step(0)
            if not self.rt.queue and not len(self.service.inbox):
                break

    def predictions(self) -> list[Prediction]:
        out = []
        for _, data in self.transport.take("prediction"):
            msg = decode("prediction", data, dims=self.rt.dims, robot="aibo")
            assert isinstance(msg, Prediction)
            out.append(msg)
        return out

    def status(self) -> Status:
        self.clock.advance(1.0)
        self.service.step(0)
        msgs = self.transport.take("status")
        st = decode("status", msgs[-1][1], dims=self.rt.dims, robot="aibo")
        assert isinstance(st, Status)
        return st


def test_lockstep_answers_each_perception_and_learns_pairs(tmp_path: Path) -> None:
    h = Harness(make_config(tmp_path))
    for t in range(20):
        h.send("perception", encode(Perception("aibo", t, t / 30, x=STREAM.x[t])))
        h.settle()
        h.send("action", encode(Action("aibo", t, t / 30, y=STREAM.y[t],
                                       label=LABELS[STREAM.labels[t]])))
        h.settle()
    preds = h.predictions()
    assert [p.tick for p in preds] == list(range(20))
    for p in preds:
        assert np.all(np.isfinite(p.mean)) and np.all(p.var > 0)
        assert p.mode == "learn+predict" and p.latency_ms >= 0
    # perception(t) came before action(t): it is answered with pairs 0..t-1 learned
    assert [p.updates for p in preds] == list(range(20))
    assert preds[0].expert == -1 and preds[0].multimap == ()
    assert preds[-1].multimap and all(e.label in LABELS for e in preds[-1].multimap)
    assert math.isclose(sum(e.p for e in preds[-1].multimap), 1.0, rel_tol=1e-6)
    st = h.status()
    assert st.updates == 20 and st.ticks == 20 and st.dropped == 0 and st.invalid == {}


def test_a_started_daemon_collects_garbage_at_quiet_moments(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Once the daemon holds collections (``gc_thresholds`` set), the loop applies the rule
    at the end of a cycle that left nothing to answer; never while the harness has none."""
    from roger_daemon.daemon.service import loop

    calls: list[tuple[int, int, int]] = []
    monkeypatch.setattr(loop, "collect_when_idle", lambda t: calls.append(t))
    h = Harness(make_config(tmp_path))
    h.pair(0)
    h.settle()
    assert calls == []
    h.service.gc_thresholds = (700, 10, 10)
    h.pair(1)
    h.settle()
    assert calls and set(calls) == {(700, 10, 10)}


def test_recordings_wait_for_a_quiet_moment_at_most_so_long() -> None:
    """``Recorders`` holds messages (in order) until a quiet poll, ``HOLD_NS`` or
    ``HOLD_MAX``; closing writes what is held; robots without a recorder record nothing."""
    from roger_daemon.config import RecordingConfig
    from roger_daemon.daemon.service import recording

    a, b = FakeRecorder(), FakeRecorder()
    recs = recording.Recorders({"a": a, "b": b}, RecordingConfig())
    clock = [0]
    recs._next_retention = 2**62  # no retention pass here
    for i in range(3):
        recs.write("a" if i != 1 else "b", f"k{i}", b"p", i, 10 + i, i)
    recs.write("ghost", "k", b"p", 0, 0, 0)
    recs.poll(lambda: clock[0], quiet=False)
    assert a.writes == [] and b.writes == [] and a.polls == 1
    clock[0] = recording.HOLD_NS - 1
    recs.poll(lambda: clock[0], quiet=False)
    assert a.writes == []
    recs.poll(lambda: clock[0], quiet=True)
    assert a.writes == [("k0", b"p", 0, 10, 0), ("k2", b"p", 2, 12, 2)]
    assert b.writes == [("k1", b"p", 1, 11, 1)]
    recs.write("a", "late", b"p", 5, 5, 5)
    recs.poll(lambda: clock[0], quiet=False)  # held from here ...
    clock[0] += recording.HOLD_NS
    recs.poll(lambda: clock[0], quiet=False)  # ... at most HOLD_NS
    assert a.writes[-1][0] == "late"
    for i in range(recording.HOLD_MAX):
        recs.write("b", "many", b"p", i, i, i)
    recs.poll(lambda: clock[0], quiet=False)
    assert len(b.writes) == 1 + recording.HOLD_MAX
    recs.write("a", "last", b"p", 6, 6, 6)
    recs.close()
    assert a.writes[-1][0] == "last" and a.closed and b.closed


class FlushingRecorder(FakeRecorder):
    """A recorder whose poll flushes once ``due`` is set (as a chunk does once a second)."""

    def __init__(self) -> None:
        super().__init__()
        self.due = False
        self.flushes = 0

    def poll(self, now_ns: int) -> bool:  # type: ignore[override]
        self.polls += 1
        flushed, self.due = self.due, False
        self.flushes += flushed
        return flushed


def test_recorders_flush_at_quiet_moments_one_per_cycle_or_once_overdue() -> None:
    """A flush compresses and writes a chunk: it waits for a quiet cycle, one per cycle, or
    ``HOLD_NS`` since the recorders were last polled (then all that are due)."""
    from roger_daemon.config import RecordingConfig
    from roger_daemon.daemon.service import recording

    a, b = FlushingRecorder(), FlushingRecorder()
    recs = recording.Recorders({"a": a, "b": b}, RecordingConfig())
    recs._next_retention = 2**62
    clock = [0]
    recs.poll(lambda: clock[0], quiet=True)  # the first poll: every recorder starts its clock
    a.due = b.due = True
    clock[0] = 1
    recs.poll(lambda: clock[0], quiet=False)  # not quiet, not overdue: nothing flushes
    assert (a.flushes, b.flushes) == (0, 0)
    recs.poll(lambda: clock[0], quiet=True)  # a flushes; b waits for the next quiet cycle
    assert (a.flushes, b.flushes, b.polls) == (1, 0, 1)
    recs.poll(lambda: clock[0], quiet=True)
    assert (a.flushes, b.flushes) == (1, 1)
    a.due = b.due = True
    clock[0] += recording.HOLD_NS  # overdue: both, in one cycle
    recs.poll(lambda: clock[0], quiet=False)
    assert (a.flushes, b.flushes) == (2, 2)


def test_lockstep_learns_complete_pairs_before_answering(tmp_path: Path) -> None:
    """A perception is answered in arrival order: after every pair whose action arrived
    before it, and without a pair whose action arrived after it, even when both reach the
    loop in one drain (a perception's own action never leaks into its prediction)."""
    h = Harness(make_config(tmp_path))
    for t in range(6):
        h.pair(t, action_first=(t % 2 == 1))  # both halves arrive before the loop runs
        h.settle()
    assert [p.updates for p in h.predictions()] == [0, 2, 2, 4, 4, 6]


def test_prediction_updates_field_matches_model_state(tmp_path: Path) -> None:
    """`updates` lets a replay recompute a prediction exactly from the same model state."""
    h = Harness(make_config(tmp_path))
    for t in range(10):
        h.pair(t)
        h.settle()
    h.send("perception", encode(Perception("aibo", 10, 0.3, x=STREAM.x[10])))
    h.settle()
    pred = h.predictions()[-1]
    assert pred.updates == 10
    again = h.rt.model.predict_one(STREAM.x[10])
    np.testing.assert_array_equal(pred.mean, again.mean)
    np.testing.assert_array_equal(pred.var, again.var)


def test_realtime_timer_publishes_for_newest_perception(tmp_path: Path) -> None:
    h = Harness(make_config(tmp_path, clock="realtime", rate_hz=30.0))
    for _ in range(10):  # idle: nothing to publish, no deadline is "missed"
        h.clock.advance(0.1)
        h.service.step(0)
    h.send("perception", encode(Perception("aibo", 0, 0.0, x=STREAM.x[0])))
    h.send("perception", encode(Perception("aibo", 1, 0.03, x=STREAM.x[1])))
    h.service.step(0)  # first tick after idling: at once, and the schedule starts from here
    assert [p.tick for p in h.predictions()] == [1]
    h.clock.advance(0.5 / 30)
    h.service.step(0)
    assert h.predictions() == []  # nothing between two ticks
    h.clock.advance(0.5 / 30)
    for _ in range(10):
        h.service.step(0)
        h.clock.advance(1 / 30)
    preds = h.predictions()
    assert len(preds) == 10
    assert {p.tick for p in preds} == {1}  # always the newest perception
    # latency grows with the age of that perception
    assert preds[-1].latency_ms > preds[0].latency_ms
    assert h.service.stats.missed_ticks == 0
    assert len(h.service.stats.jitter_ms.values) == 10
    assert h.service.stats.jitter_ms.pct(99) == pytest.approx(0.0, abs=0.01)
    # a stall of 3.5 periods: the late tick publishes, the skipped ones are counted
    h.clock.advance(3.5 / 30)
    h.service.step(0)
    assert len(h.predictions()) == 1 and h.service.stats.missed_ticks == 3


def test_modes_and_reset_and_checkpoint_controls(tmp_path: Path) -> None:
    h = Harness(make_config(tmp_path))

    def control(op: str, mode: str = "") -> None:
        h.send("control", encode(Control("aibo", 0, 0.0, op=op, mode=mode)))
        h.settle()

    control("mode", "predict")
    for t in range(5):
        h.pair(t)
        h.settle()
    assert h.rt.updates == 0 and len(h.predictions()) == 5  # predict: no learning
    control("mode", "learn")
    for t in range(5, 10):
        h.pair(t)
        h.settle()
    assert h.rt.updates == 5 and h.predictions() == []  # learn: no predictions
    control("mode", "pause")
    h.pair(10)
    h.settle()
    assert h.rt.updates == 5 and h.predictions() == []
    control("checkpoint")
    files = list_checkpoints(tmp_path / "ckpt", "aibo")
    assert len(files) == 1
    assert read_checkpoint(files[0]).meta.updates == 5
    control("reset")
    assert h.rt.updates == 0 and h.rt.vocab == []
    assert h.status().mode == "pause"


def test_full_queue_drops_counts_and_logs(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    h = Harness(make_config(tmp_path, queue_size=3, mode="learn"))  # no answer learns them
    caplog.set_level(logging.WARNING)
    for t in range(8):  # all arrive before the loop runs: 3 fit, 5 are dropped
        h.pair(t)
    h.service.step(0)
    assert h.rt.dropped == 5
    assert "training queue full" in caplog.text
    h.settle()
    st = h.status()
    assert st.dropped == 5 and st.updates == 3 and st.queue_depth == 0


BAD = [
    ("perception", b"\xc1garbage", "not_msgpack"),
    ("perception", msgpack.packb([1, 2, 3]), "not_a_map"),
    ("perception", msgpack.packb({"v": 1, "robot": "aibo", "tick": 1, "t": 0.0, "stamp_ns": 1,
                                  "x": [0.0] * 22}), "wrong_dimension"),
    ("perception", msgpack.packb({"v": 1, "robot": "aibo", "tick": 1, "t": 0.0, "stamp_ns": 1,
                                  "x": [0.0] * 22 + [float("nan")]}), "not_finite"),
    ("action", msgpack.packb({"v": 1, "robot": "aibo", "tick": 1, "t": 0.0, "stamp_ns": 1,
                              "y": [float("inf")] * 9, "label": "seek"}), "not_finite"),
    ("action", msgpack.packb({"v": 1, "robot": "aibo", "tick": "one", "t": 0.0, "stamp_ns": 1,
                              "y": [0.0] * 9, "label": "seek"}), "wrong_type"),
    ("perception", b"\x00" * (MAX_PAYLOAD_BYTES + 1), "oversized"),
    ("perception", msgpack.packb({"v": 1, "robot": "ghost", "tick": 1, "t": 0.0, "stamp_ns": 1,
                                  "x": [0.0] * 23}), "unknown_robot"),
    ("control", msgpack.packb({"v": 1, "robot": "aibo", "tick": 1, "t": 0.0, "stamp_ns": 1,
                               "op": "explode", "mode": ""}), "bad_value"),
]


def test_bad_input_is_counted_by_reason_and_changes_nothing(tmp_path: Path) -> None:
    h = Harness(make_config(tmp_path))
    for t in range(6):
        h.pair(t)
        h.settle()
    before = array_digest(h.rt.model.state_dict())
    for kind, payload, _ in BAD:
        h.send(kind, payload)
    # a served kind for a robot nobody serves
    h.send("perception", encode(Perception("ghost", 1, 0.0, x=STREAM.x[0])), robot="ghost")
    h.settle()
    st = h.status()
    want: dict[str, int] = {}
    for _, _, reason in BAD:
        want[reason] = want.get(reason, 0) + 1
    want["unknown_robot"] += 1
    assert st.invalid == want
    assert st.updates == 6 and st.ticks == 6
    assert array_digest(h.rt.model.state_dict()) == before
    # still serving
    h.pair(6)
    h.settle()
    assert h.predictions()[-1].tick == 6 and h.rt.updates == 7


def test_unpaired_actions_are_counted(tmp_path: Path) -> None:
    h = Harness(make_config(tmp_path, pair_window=2))
    for t in range(5):
        h.send("action", encode(Action("aibo", t, 0.0, y=STREAM.y[t], label="seek")))
    h.settle()
    assert h.status().info["unpaired_actions"] == 3


def test_pairs_are_counted_by_source_and_corrections(tmp_path: Path) -> None:
    """Each queued pair counts under its action's source (status info pairs_teacher /
    pairs_robot) and a teacher's correction also under corrections (docs/teach.md)."""
    h = Harness(make_config(tmp_path))
    tags = [("teacher", False)] * 3 + [("teacher", True)] * 2 + [("robot", False), ("", False)]
    for t, (source, correction) in enumerate(tags):
        h.send("perception", encode(Perception("aibo", t, t / 30, x=STREAM.x[t])))
        h.send("action", encode(Action("aibo", t, t / 30, y=STREAM.y[t], source=source,
                                       correction=correction)))
    h.settle()
    info = h.status().info
    assert h.rt.updates == len(tags)
    assert (info["pairs_teacher"], info["pairs_robot"], info["corrections"]) == (5, 1, 2)


def test_shutdown_checkpoint_and_resume_identical(tmp_path: Path) -> None:
    cfg = make_config(tmp_path, queue_size=64)
    h = Harness(cfg)
    for t in range(30):
        h.pair(t)
        h.settle()
    h.pair(30)  # queued, maybe unlearned at shutdown: saved with the checkpoint
    h.service.step(0)
    h.service.shutdown()
    assert h.transport.closed and h.transport.intake_stopped
    files = list_checkpoints(tmp_path / "ckpt", "aibo")
    assert len(files) == 1
    saved = read_checkpoint(files[0])
    rt, resumed = build_robot(cfg, cfg.robots[0], fresh=False)
    assert resumed == str(files[0])
    assert rt.updates == saved.meta.updates
    back = rt.model.state_dict()
    assert set(back) == set(saved.model)
    for k in back:
        np.testing.assert_array_equal(back[k], saved.model[k])
    assert rt.vocab == h.rt.vocab and np.array_equal(rt.codes, h.rt.codes)
    assert rt.ticks == 31
    fresh, none = build_robot(cfg, cfg.robots[0], fresh=True)
    assert fresh.updates == 0 and none == ""


def test_periodic_checkpoints_by_updates_and_by_time(tmp_path: Path) -> None:
    h = Harness(make_config(tmp_path, checkpoint={"every_updates": 4, "every_s": 10.0}))
    for t in range(9):
        h.pair(t)
        h.settle()
    files = list_checkpoints(tmp_path / "ckpt", "aibo")
    assert [read_checkpoint(f).meta.updates for f in reversed(files)] == [4, 8]
    h.clock.advance(5.0)
    h.service.step(0)
    assert len(list_checkpoints(tmp_path / "ckpt", "aibo")) == 2  # 1 change, 5 s: not yet
    h.clock.advance(5.0)
    h.service.step(0)
    files = list_checkpoints(tmp_path / "ckpt", "aibo")
    assert read_checkpoint(files[0]).meta.updates == 9
    assert read_checkpoint(files[0]).meta.reason == "periodic"
    h.clock.advance(20.0)
    h.service.step(0)
    assert len(list_checkpoints(tmp_path / "ckpt", "aibo")) == 3  # nothing changed: none


def test_corrupt_newest_checkpoint_is_skipped(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    cfg = make_config(tmp_path)
    h = Harness(cfg)
    for t in range(5):
        h.pair(t)
        h.settle()
    h.send("control", encode(Control("aibo", 0, 0.0, op="checkpoint")))
    h.settle()
    h.pair(5)
    h.settle()
    h.service.shutdown()
    first, = [p for p in list_checkpoints(tmp_path / "ckpt", "aibo") if p.name.endswith("1.npz")]
    newest = list_checkpoints(tmp_path / "ckpt", "aibo")[0]
    data = newest.read_bytes()
    newest.write_bytes(data[: len(data) // 2])
    caplog.set_level(logging.WARNING)
    rt, resumed = build_robot(cfg, cfg.robots[0], fresh=False)
    assert resumed == str(first) and rt.updates == 5
    assert f"skipping corrupt or unusable checkpoint {newest}" in caplog.text


def test_recorder_sees_every_message_in_and_out(tmp_path: Path) -> None:
    rec = FakeRecorder()
    h = Harness(make_config(tmp_path), recorder=rec)
    h.pair(0)
    h.send("command", encode(Action("aibo", 0, 0.0, y=STREAM.y[0], label="")))  # invalid command
    h.send("perception", b"junk")
    h.settle()
    h.status()
    h.service.shutdown()
    kinds = [w[0].rsplit("/", 1)[1] for w in rec.writes]
    assert kinds.count("perception") == 2 and kinds.count("action") == 1
    assert kinds.count("prediction") == 1 and kinds.count("status") >= 1
    assert kinds.count("command") == 1
    perc = next(w for w in rec.writes if w[0] == keys.perception("aibo") and w[4] == 0
                and w[1] != b"junk")
    assert perc[3] == decode("perception", perc[1]).stamp_ns  # publish time: the sender's
    assert rec.polls > 0 and rec.closed


def test_majority_labels() -> None:
    vocab = ["seek", "", "aim"]
    assign = np.array([4, 4, 4, 7, 7, 9])
    codes = np.array([0, 2, 2, 1, 1, 0])
    assert majority_labels(assign, codes, vocab) == {4: "aim", 7: "", 9: "seek"}
    assert majority_labels(np.array([], dtype=np.int64), np.array([], dtype=np.int32), []) == {}


def test_liveliness_token_and_subscriptions(tmp_path: Path) -> None:
    h = Harness(make_config(tmp_path))
    # the daemon's token, and the token of the robot it serves (a standby watches it)
    assert h.transport.tokens == [keys.daemon_liveliness("roger"),
                                  keys.active_token("roger", "aibo", 0)]
    # one subscriber on roger/** (order-preserving); other daemons' outputs are ignored
    assert h.transport.inject(keys.prediction("aibo"), b"x") == 1
    assert h.transport.inject(keys.status("aibo"), b"x") == 1
    h.settle()
    assert h.transport.published == [] and h.rt.invalid == {} and h.service.unserved == {}


def test_inline_answers_are_the_one_encoding_stamped_on_the_loops_clock(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Inline as in a learner worker, a prediction is published as ``RobotRuntime.answer``'s
    bytes (``encode_prediction``) with its publish-time fields stamped on the service's clock:
    the message dataclass is never encoded on the way (issue 58: one prediction encoder)."""
    def refuse(self: Prediction) -> dict[str, Any]:
        raise AssertionError("a daemon answer encoded the Prediction dataclass")

    monkeypatch.setattr(Prediction, "body", refuse)
    h = Harness(make_config(tmp_path))
    try:
        for t in range(5):
            h.pair(t)
            h.clock.advance(0.01)
            h.settle()
        preds = h.predictions()
        assert [p.tick for p in preds] == list(range(5))
        assert [p.updates for p in preds] == list(range(5))
        assert all(p.stamp_ns - h.clock.wall in range(10**9, 10**9 + 10**8) for p in preds)
        assert len({p.stamp_ns for p in preds}) == 5  # each stamped when it was published
    finally:
        h.service.shutdown()
