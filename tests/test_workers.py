"""Learner worker processes (``[daemon] workers = "process"``): real worker subprocesses,
the service loop over the in-memory transport, compared with the in-process model.

Bounded loops with generous deadlines; no timing assertions.
"""

from __future__ import annotations

import contextlib
import os
import signal
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from protocols import Action, Control, Perception, decode, encode, keys
from protocols.messages import Prediction
from roger_daemon.config import ConfigError, DaemonConfig, parse_config
from roger_daemon.daemon.checkpoint import list_checkpoints, read_checkpoint
from roger_daemon.daemon.learners import ProcessLearners, WorkerError
from roger_daemon.daemon.main import build_robot
from roger_daemon.daemon.service import Service
from roger_daemon.daemon.wal import read_records, wal_dir
from roger_daemon.learner.synthetic import subtask_stream
from roger_daemon.testing import MemoryTransport

LABELS = ("seek", "trap", "aim", "kick")
STREAM = subtask_stream(60)
DEADLINE_S = 120.0


def make_config(tmp_path: Path, name: str, clock: str = "lockstep",
                **checkpoint: Any) -> DaemonConfig:
    return parse_config({
        "daemon": {"clock": clock},
        "robots": [{"id": "aibo"}, {"id": "b2"}],
        "checkpoint": {"dir": str(tmp_path / name), "every_updates": 0, "every_s": 0,
                       **checkpoint},
        "recording": {"enabled": False},
    })


class Loop:
    """A service over the memory transport, inline or with worker processes: one process
    serving both robots unless ``processes`` asks for more (the daemon's default, one per
    core, would make the pool, and each test's cost, depend on the machine's core count;
    docs/testing.md, *Keeping it*)."""

    def __init__(self, cfg: DaemonConfig, *, process: bool, nice: int = 0,
                 processes: int = 1) -> None:
        from roger_daemon.daemon import wal

        self.transport = MemoryTransport()
        self.robots = {}
        for r in cfg.robots:
            rt, _ = build_robot(cfg, r, fresh=True)
            wal.start(rt, wal_dir(cfg.checkpoint.dir, r.id), checkpoint_seq=None, replay=False,
                      fresh=True)
            self.robots[r.id] = rt
        self.learners = ProcessLearners(self.robots, {r.id: r for r in cfg.robots},
                                        processes=processes, timeout_s=DEADLINE_S,
                                        nice=nice) if process else None
        self.service = Service(cfg, self.transport, self.robots, sync_checkpoints=True,
                               learners=self.learners)
        self.service.start()
        self.preds: list[Prediction] = []

    def send(self, robot: str, t: int) -> None:
        p = encode(Perception(robot, t, t / 30, x=STREAM.x[t]))
        a = encode(Action(robot, t, t / 30, y=STREAM.y[t], label=LABELS[STREAM.labels[t]]))
        self.transport.inject(keys.key(robot, "action"), a)  # action first: learned, then
        self.transport.inject(keys.key(robot, "perception"), p)  # prediction(t) includes t

    def send_paced(self, robot: str, ticks: range) -> None:
        """Send ``ticks`` one loop step apart (realtime: the loop keeps running)."""
        for t in ticks:
            self.send(robot, t)
            self.service.step(0.005)

    def collect_until(self, done: Any, what: str) -> Prediction:
        """Collect until the newest prediction satisfies ``done`` (bounded by the deadline)."""
        end = time.monotonic() + DEADLINE_S
        while not self.preds or not done(self.preds[-1]):
            assert time.monotonic() < end, what
            self.collect(len(self.preds) + 1)
        return self.preds[-1]

    def collect(self, n: int) -> list[Prediction]:
        """Step until ``n`` predictions in all were published (bounded by the deadline)."""
        end = time.monotonic() + DEADLINE_S
        while len(self.preds) < n:
            assert time.monotonic() < end, f"only {len(self.preds)} of {n} predictions"
            self.service.step(0.01)
            for key, data in self.transport.take("prediction"):
                robot = key.split("/")[1]
                msg = decode("prediction", data, dims=self.robots[robot].dims, robot=robot)
                assert isinstance(msg, Prediction)
                self.preds.append(msg)
        return self.preds


def _same_prediction(a: Prediction, b: Prediction) -> None:
    assert (a.robot, a.tick, a.updates, a.expert, a.mode) == (
        b.robot, b.tick, b.updates, b.expert, b.mode)
    np.testing.assert_array_equal(a.mean, b.mean)
    np.testing.assert_array_equal(a.var, b.var)
    assert len(a.multimap) == len(b.multimap)
    for ea, eb in zip(a.multimap, b.multimap, strict=True):
        assert (ea.expert, ea.p, ea.n, ea.label) == (eb.expert, eb.p, eb.n, eb.label)
        np.testing.assert_array_equal(ea.mean, eb.mean)
        np.testing.assert_array_equal(ea.var, eb.var)


def test_workers_config_is_validated(tmp_path: Path) -> None:
    cfg = make_config(tmp_path, "c")
    assert cfg.workers == "auto" and cfg.learner_workers == "process"  # two robots
    one = parse_config({"robots": [{"id": "aibo"}]})
    assert one.workers == "auto" and one.learner_workers == "inline"  # one robot: lower latency
    assert parse_config({"daemon": {"workers": "process"}}).learner_workers == "process"
    with pytest.raises(ConfigError) as err:
        parse_config({"daemon": {"workers": "threads"}})
    assert err.value.key == "daemon.workers"
    assert '"auto", "process", "inline"' in str(err.value)
    assert cfg.worker_nice == 5  # either clock (docs/fleet.md, *Scheduling and fairness*)
    assert parse_config({"daemon": {"worker_nice": 0}}).worker_nice == 0
    for bad in (20, -1, 2.5, True):
        with pytest.raises(ConfigError) as err:
            parse_config({"daemon": {"worker_nice": bad}})
        assert err.value.key == "daemon.worker_nice"
    assert cfg.worker_processes == 0  # one per usable core
    assert parse_config({"daemon": {"worker_processes": 3}}).worker_processes == 3
    for bad in (-1, 1.5, "auto", True):
        with pytest.raises(ConfigError) as err:
            parse_config({"daemon": {"worker_processes": bad}})
        assert err.value.key == "daemon.worker_processes"


def test_the_pool_has_one_process_per_core_and_never_more_than_robots(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """``worker_processes = 0``: one per usable core; never more processes than robots; the
    cores shared out among the processes for their learners' threads."""
    from roger_daemon.daemon import worker_procs

    monkeypatch.setattr(worker_procs, "usable_cores", lambda: 4)
    assert [worker_procs.pool_size(r) for r in (1, 2, 4, 8)] == [1, 2, 4, 4]
    assert [worker_procs.pool_size(8, p) for p in (1, 3, 16)] == [1, 3, 8]
    assert [worker_procs.threads_per_worker(p) for p in (1, 2, 4, 8)] == [4, 2, 1, 1]


def test_workers_run_nicer_than_the_loop(tmp_path: Path) -> None:
    """``[daemon] worker_nice``: each worker lowers its own CPU priority at start."""
    proc = Loop(make_config(tmp_path, "n"), process=True, nice=3)
    assert proc.learners is not None
    try:
        mine = os.getpriority(os.PRIO_PROCESS, 0)
        for s in proc.learners.slots.values():
            assert os.getpriority(os.PRIO_PROCESS, s.proc.pid) == min(19, mine + 3)
        assert proc.service.status_of(proc.robots["aibo"], 0).info["worker_nice"] == 3
    finally:
        proc.service.shutdown()


def test_realtime_tick_publishes_the_prediction_prepared_on_arrival(tmp_path: Path) -> None:
    """Realtime with workers: the prediction for a perception is computed when it arrives and
    the next tick publishes it; when no newer perception comes, it is computed again as the
    model learns the queued pairs. It equals the lockstep answer of a model with the same
    updates (so replay recomputes it), and every pair it counts is in the write-ahead log."""
    proc = Loop(make_config(tmp_path, "rt", clock="realtime"), process=True)
    try:
        proc.send_paced("aibo", range(10))
        last = proc.collect_until(lambda p: (p.tick, p.updates) == (9, 10),
                                  "no prediction counting every pair")
        assert all(p.tick in range(10) for p in proc.preds)
        assert [p.updates for p in proc.preds] == sorted(p.updates for p in proc.preds)
        pairs = [r for r in read_records(wal_dir(tmp_path / "rt", "aibo")) if r.kind == "pair"]
        assert len(pairs) == 10
    finally:
        proc.service.shutdown()
    ref = Loop(make_config(tmp_path, "ref"), process=False)
    try:
        for t in range(10):
            ref.send("aibo", t)
        want = [p for p in ref.collect(10) if p.tick == 9][0]
        _same_prediction(replace(want, mode=last.mode), last)
    finally:
        ref.service.shutdown()


def test_no_prediction_is_started_in_the_quiet_window_before_a_tick(tmp_path: Path) -> None:
    """A perception that arrives too close to the tick to be ready for it waits for the tick
    (the cores are left to publishing); the tick sends it."""
    proc = Loop(make_config(tmp_path, "q", clock="realtime"), process=True)
    learners = proc.learners
    assert learners is not None
    try:
        slot = learners.slots["aibo"]
        learners.windows.deadline_ns = time.monotonic_ns() + 500_000  # the tick in 0.5 ms
        learners.prepare(proc.robots["aibo"], Perception("aibo", 0, 0.0, x=STREAM.x[0]), 0)
        assert slot.waiting is not None and slot.predicts == 0
        learners.new_tick(time.monotonic_ns() + 10**9, published=False)  # no delivery window
        assert slot.waiting is None and slot.predicts == 1
        assert learners.prepared([proc.robots["b2"]]) == [] and slot.busy_ticks == 0
        assert learners.slots["b2"].busy_ticks == 1  # b2: nothing prepared yet
    finally:
        proc.service.shutdown()


def test_nothing_goes_to_a_worker_in_the_delivery_window_after_a_tick(
        tmp_path: Path) -> None:
    """After a tick that published, its predictions are delivered before the workers wake:
    a perception to prepare and a queued pair wait until the window closes (the loop's wait
    ends then), and then the perception's request goes first."""
    proc = Loop(make_config(tmp_path, "dw", clock="realtime"), process=True)
    learners = proc.learners
    assert learners is not None
    try:
        aibo, slot = proc.robots["aibo"], learners.slots["aibo"]
        learners.new_tick(time.monotonic_ns() + 10**9)  # it published
        wake = learners.windows.wake_ns()
        assert learners.windows.delivering() and wake is not None
        aibo.on_perception(Perception("aibo", 0, 0.0, x=STREAM.x[0]), 0)
        aibo.on_action(Action("aibo", 0, 0.0, y=STREAM.y[0], label="seek"))
        learners.prepare(aibo, Perception("aibo", 1, 1 / 30, x=STREAM.x[1]), 0)
        learners.feed()
        assert (slot.predicts, slot.learns, len(aibo.queue)) == (0, 0, 1)  # all held
        assert slot.waiting is not None
        assert proc.service._next_deadline(time.monotonic_ns()) <= wake
        while learners.windows.delivering():
            time.sleep(0.001)
        assert learners.windows.wake_ns() is None
        learners.feed()
        assert [op for op, _ in slot.pending] == ["predict", "learn"]
        assert slot.waiting is None and len(aibo.queue) == 0
        learners.drain()
        learners.new_tick(time.monotonic_ns() + 10**9, published=False)  # nothing published:
        assert not learners.windows.delivering()  # no window
    finally:
        proc.service.shutdown()


def test_lockstep_starts_no_learning_while_a_prediction_is_answered(tmp_path: Path) -> None:
    """Without a timer the answers go first: a pair queued while any robot's prediction is
    in flight waits in the queue; once answered, feeding sends it."""
    proc = Loop(make_config(tmp_path, "hold"), process=True, processes=2)  # a process each
    learners = proc.learners
    assert learners is not None
    try:
        aibo, b2 = proc.robots["aibo"], proc.robots["b2"]
        learners.predict(aibo, Perception("aibo", 0, 0.0, x=STREAM.x[0]), 0)
        assert learners.answering()
        b2.on_perception(Perception("b2", 0, 0.0, x=STREAM.x[0]), 0)
        b2.on_action(Action("b2", 0, 0.0, y=STREAM.y[0], label="seek"))
        assert len(b2.queue) == 1  # b2's pair of tick 0
        learners.feed()
        assert learners.slots["b2"].learns == 0 and len(b2.queue) == 1  # held
        learners._wait(lambda: not learners.answering(), "test")
        learners.feed()
        assert learners.slots["b2"].learns == 1 and len(b2.queue) == 0  # sent
        learners.drain()
    finally:
        proc.service.shutdown()


def test_a_worker_process_has_one_learning_step_in_flight_its_robots_in_turn(
        tmp_path: Path) -> None:
    """With one process serving both robots, feeding sends one learn request at a time (a
    prediction then waits for one other robot's step at most), and the robots take turns;
    a robot's own pairs still go before its prediction request, however many."""
    proc = Loop(make_config(tmp_path, "turns"), process=True, processes=1)
    learners = proc.learners
    assert learners is not None and len(learners.processes) == 1
    wp = learners.processes[0]
    try:
        aibo, b2 = proc.robots["aibo"], proc.robots["b2"]
        for t in range(2):
            for rt in (aibo, b2):
                rt.on_perception(Perception(rt.robot, t, t / 30, x=STREAM.x[t]), 0)
                rt.on_action(Action(rt.robot, t, t / 30, y=STREAM.y[t], label="seek"))
        assert len(aibo.queue) == len(b2.queue) == 2
        sent = []
        for _ in range(4):
            learners.feed()
            assert learners.learns_in(wp) == 1  # one step in flight in the process
            sent.append("aibo" if learners.slots["aibo"].learns else "b2")
            learners._wait(lambda: learners.learns_in(wp) == 0, "test")
        assert sent == ["aibo", "b2", "aibo", "b2"]
        assert aibo.updates == b2.updates == 2
        aibo.on_perception(Perception("aibo", 2, 2 / 30, x=STREAM.x[2]), 0)
        aibo.on_action(Action("aibo", 2, 2 / 30, y=STREAM.y[2], label="seek"))
        b2.on_perception(Perception("b2", 2, 2 / 30, x=STREAM.x[2]), 0)
        b2.on_action(Action("b2", 2, 2 / 30, y=STREAM.y[2], label="seek"))
        learners.feed()  # one of them in flight, the other's pair held
        learners.learn_all(b2)  # before b2's prediction: its own pair, whatever is in flight
        assert len(b2.queue) == 0 and learners.slots["b2"].learns == 1
        learners.drain()
    finally:
        proc.service.shutdown()


@pytest.mark.parametrize("processes", [2, 1], ids=["a-process-each", "one-process-for-both"])
def test_worker_equals_in_process_model_bit_for_bit(tmp_path: Path, processes: int) -> None:
    """Lockstep predictions, label majorities, checkpoints and write-ahead log records of
    two robots learned by worker processes (one each, or one serving both models) equal
    those of the in-process loop."""
    inline = Loop(make_config(tmp_path, "inline"), process=False)
    proc = Loop(make_config(tmp_path, "process"), process=True, processes=processes)
    assert proc.learners is not None and len(proc.learners.processes) == processes
    assert len({s.proc.pid for s in proc.learners.slots.values()}) == processes
    try:
        for t in range(30):
            for loop in (inline, proc):
                loop.send("aibo", t)
                loop.send("b2", 30 + t)
        a, b = inline.collect(60), proc.collect(60)
        key = lambda p: (p.robot, p.tick)  # noqa: E731
        for pa, pb in zip(sorted(a, key=key), sorted(b, key=key), strict=True):
            _same_prediction(pa, pb)
        assert max(p.updates for p in b if p.robot == "aibo") == 30
        assert any(e.label for p in b for e in p.multimap)
        for loop in (inline, proc):
            loop.transport.inject(keys.key("aibo", "control"),
                                  encode(Control("aibo", 0, 0.0, op="checkpoint")))
            loop.service.step(0.01)
        ck = {}
        for name, loop in (("inline", inline), ("process", proc)):
            loop.service.shutdown()
            paths = list_checkpoints(tmp_path / name, "aibo")
            ck[name] = read_checkpoint(paths[0])
            assert ck[name].meta.updates == 30
        assert ck["inline"].meta.model_digest == ck["process"].meta.model_digest
        np.testing.assert_array_equal(ck["inline"].daemon["label_codes"],
                                      ck["process"].daemon["label_codes"])
        recs = [[(r.kind, r.index, r.tick) for r in read_records(wal_dir(tmp_path / n, "b2"))]
                for n in ("inline", "process")]
        assert recs[0] == recs[1] and len(recs[0]) == 31  # fresh + 30 pairs
    finally:
        for loop in (inline, proc):
            loop.service.shutdown()


def test_inline_loop_commits_every_answered_robot_before_publishing(tmp_path: Path) -> None:
    """Acknowledged means durable with several robots in one loop: the logs of the robots a
    step answers are committed together (in parallel) before any of them is published."""
    inline = Loop(make_config(tmp_path, "inline"), process=False)
    seen: list[tuple[str, bool, bool]] = []
    publish = inline.service.outbox.prediction

    def checked(robot: str, payload: bytes, stamp_ns: int, tick: int) -> None:
        walls = [rt.wal for rt in inline.robots.values()]
        assert all(w is not None for w in walls)
        msg = decode("prediction", payload)
        assert isinstance(msg, Prediction)
        seen.append((robot, any(w.dirty for w in walls if w is not None), msg.updates > 0))
        publish(robot, payload, stamp_ns, tick)

    inline.service.outbox.prediction = checked  # type: ignore[method-assign]
    try:
        for t in range(10):
            inline.send("aibo", t)
            inline.send("b2", 20 + t)  # both robots answered in one step
        inline.collect(20)
        assert len(seen) == 20 and {r for r, _, _ in seen} == {"aibo", "b2"}
        assert sum(learned for _, _, learned in seen) == 20
        assert not any(dirty for _, dirty, _ in seen), seen
    finally:
        inline.service.shutdown()


def test_reset_drains_the_worker_first(tmp_path: Path) -> None:
    proc = Loop(make_config(tmp_path, "p"), process=True)
    try:
        for t in range(5):
            proc.send("aibo", t)
        proc.collect(5)
        proc.transport.inject(keys.key("aibo", "control"),
                              encode(Control("aibo", 0, 0.0, op="reset")))
        proc.send("aibo", 5)
        preds = proc.collect(6)
        assert preds[-1].updates == 1  # the fresh model learned pair 5 only
        recs = read_records(wal_dir(tmp_path / "p", "aibo"))
        assert [r.kind for r in recs] == ["fresh"] + ["pair"] * 5 + ["fresh", "pair"]
    finally:
        proc.service.shutdown()


@pytest.mark.parametrize("process", [False, True], ids=["inline", "process"])
def test_a_pair_queued_before_a_reset_is_learned_by_the_old_model(tmp_path: Path,
                                                                  process: bool) -> None:
    """Lockstep: action(5) completes pair 5 after prediction(5); if the loop drains it and a
    reset in one cycle (a stall delayed it), pair 5 is still learned, and logged, before the
    reset: which pairs the old model learned depends on the messages' order, not on timing."""
    loop = Loop(make_config(tmp_path, "r"), process=process)
    try:
        for t in range(5):
            loop.send("aibo", t)
        loop.transport.inject(keys.key("aibo", "perception"),
                              encode(Perception("aibo", 5, 5 / 30, x=STREAM.x[5])))
        loop.collect(6)
        loop.transport.inject(keys.key("aibo", "action"), encode(
            Action("aibo", 5, 5 / 30, y=STREAM.y[5], label=LABELS[STREAM.labels[5]])))
        loop.transport.inject(keys.key("aibo", "control"),
                              encode(Control("aibo", 0, 0.0, op="reset")))
        loop.service.step(0)  # both drained in one cycle
        loop.send("aibo", 6)
        assert loop.collect(7)[-1].updates == 1  # the fresh model learned pair 6 only
        recs = read_records(wal_dir(tmp_path / "r", "aibo"))
        assert [r.kind for r in recs] == ["fresh"] + ["pair"] * 6 + ["fresh", "pair"]
        assert [r.tick for r in recs if r.kind == "pair"] == [0, 1, 2, 3, 4, 5, 6]
    finally:
        loop.service.shutdown()


def test_shutdown_learns_queue_and_checkpoints(tmp_path: Path) -> None:
    cfg = make_config(tmp_path, "s", shutdown_learn_s=3.0)
    proc = Loop(cfg, process=True)
    for t in range(20):  # queued pairs, never answered: learned by the shutdown drain
        a = encode(Action("aibo", t, t / 30, y=STREAM.y[t], label="seek"))
        p = encode(Perception("aibo", t, t / 30, x=STREAM.x[t]))
        proc.transport.inject(keys.key("aibo", "perception"), p)
        proc.transport.inject(keys.key("aibo", "action"), a)
    proc.service.shutdown()
    ck = read_checkpoint(list_checkpoints(tmp_path / "s", "aibo")[0])
    assert ck.meta.reason == "shutdown"
    assert ck.meta.updates + len(ck.daemon["queue_ticks"]) == 20
    assert len([r for r in read_records(wal_dir(tmp_path / "s", "aibo"))
                if r.kind == "pair"]) == ck.meta.updates
    assert all(s.proc.poll() is not None for s in proc.learners.slots.values())


@pytest.mark.parametrize("processes", [2, 1], ids=["a-process-each", "one-process-for-both"])
def test_worker_crash_is_detected_and_reported(tmp_path: Path, processes: int) -> None:
    proc = Loop(make_config(tmp_path, "k"), process=True, processes=processes)
    assert proc.learners is not None
    pid = proc.learners.slots["b2"].proc.pid
    serving = r" \(serving aibo, b2\)" if processes == 1 else ""
    try:
        proc.send("aibo", 0)
        proc.collect(1)
        os.kill(pid, signal.SIGKILL)
        proc.send("b2", 1)
        with pytest.raises(WorkerError, match=rf"b2: learner worker pid \d+{serving} failed"):
            end = time.monotonic() + DEADLINE_S
            while time.monotonic() < end:
                proc.service.step(0.01)
    finally:
        proc.service.abort()
    assert all(s.proc.poll() is not None for s in proc.learners.slots.values())


def _maps_numba(pid: int) -> bool:
    """Whether process ``pid`` has numba's compiler (llvmlite's library) mapped."""
    return "llvmlite" in Path(f"/proc/{pid}/maps").read_text()


@contextlib.contextmanager
def _fed_daemon(tmp_path: Path, ticks: int, **daemon_cfg: Any
                ) -> Iterator[tuple[Path, Any, Any]]:
    """A real daemon serving robots ``aibo`` and ``b2`` (worker processes, real Zenoh on
    loopback) whose first ``ticks`` perceptions were answered and actions sent: yields its
    config file, the ``DaemonProcess`` and the ``Client``; closes and kills them after."""
    from roger_daemon.harness import Client, DaemonProcess, free_port, write_config

    port = free_port()
    cfg = write_config(tmp_path / "d.toml", port=port, workdir=tmp_path,
                       robots=({"id": "aibo"}, {"id": "b2"}), daemon=daemon_cfg)
    daemon = DaemonProcess(cfg)
    client = None
    try:
        daemon.wait_ready(DEADLINE_S)
        client = Client(f"tcp/127.0.0.1:{port}")
        client.wait_daemon(DEADLINE_S)
        for t in range(ticks):
            client.perception(t, STREAM.x[t])
            client.wait_prediction(t, timeout=DEADLINE_S)
            client.action(t, STREAM.y[t], LABELS[STREAM.labels[t]])
        yield cfg, daemon, client
    finally:
        if client is not None:
            client.close()
        daemon.kill()


@pytest.mark.integration
@pytest.mark.skipif(not Path("/proc/self/maps").is_file(), reason="needs Linux's /proc")
def test_with_workers_only_the_workers_load_the_compiled_kernels(tmp_path: Path) -> None:
    """A real daemon with two robots (worker processes): the workers warm up the learner's
    kernels and the loop's process does not load numba at all while it serves (docs/fleet.md,
    *The design*: ~124 MB of its memory, ~312 MB on a cold cache)."""
    # learning and predicting happen; one worker process serves both robots
    with _fed_daemon(tmp_path, 4, worker_processes=1) as (_, daemon, client):
        st = client.wait_status(lambda s: s.info.get("workers") == "process" and s.updates >= 3,
                                timeout=DEADLINE_S)
        assert _maps_numba(int(st.info["worker_pid"]))
        assert not _maps_numba(daemon.proc.pid)


@pytest.mark.slow
@pytest.mark.integration
@pytest.mark.parametrize("processes", [0, 1], ids=["default-pool", "one-process-for-both"])
def test_daemon_stops_when_a_worker_dies_and_recovers_every_acknowledged_pair(
    tmp_path: Path, processes: int,
) -> None:
    """A real daemon (worker processes, real Zenoh on loopback): SIGKILL one robot's worker
    (with ``worker_processes = 1`` the one serving both robots); the daemon reports it and
    exits 1 (not hung); a restart re-learns every acknowledged pair from the write-ahead
    log."""
    from roger_daemon.harness import DaemonProcess

    with _fed_daemon(tmp_path, 12, worker_processes=processes) as (cfg, daemon, client):
        client.perception(12, STREAM.x[12])
        acked = client.wait_prediction(12, timeout=DEADLINE_S).updates
        assert acked == 12
        st = client.wait_status(lambda s: s.info.get("workers") == "process",
                                timeout=DEADLINE_S)
        os.kill(int(st.info["worker_pid"]), signal.SIGKILL)
        assert daemon.proc.wait(DEADLINE_S) == 1
        assert "learner worker pid" in daemon.log() and "failed" in daemon.log()
    again = DaemonProcess(cfg, log=tmp_path / "again.log")
    try:
        again.wait_ready(DEADLINE_S)
        assert "re-learned 12 pairs" in again.log()
        code, _ = again.terminate(DEADLINE_S)
        assert code == 0
    finally:
        again.kill()
    assert read_checkpoint(list_checkpoints(tmp_path / "checkpoints", "aibo")[0]) \
        .meta.updates == 12


def test_realtime_reset_publishes_nothing_from_the_old_model(tmp_path: Path) -> None:
    """A reset forgets the prepared prediction: after it, every prediction published counts
    only pairs learned after the reset."""
    proc = Loop(make_config(tmp_path, "rr", clock="realtime"), process=True)
    try:
        proc.send_paced("aibo", range(8))
        proc.collect_until(lambda p: p.updates >= 8, "the pairs before the reset never counted")
        proc.transport.inject(keys.key("aibo", "control"),
                              encode(Control("aibo", 0, 0.0, op="reset")))
        proc.service.step(0.005)
        assert proc.learners is not None
        assert proc.learners.prepared([proc.robots["aibo"]]) == []  # the old one is gone
        before = len(proc.preds)
        proc.send("aibo", 8)
        proc.collect(before + 5)
        after = proc.preds[before:]
        assert all(p.updates <= 1 for p in after), [p.updates for p in after]
        assert after[-1].tick == 8
    finally:
        proc.service.shutdown()


def test_idle_worker_counts_labels_ahead_and_predicts_the_same() -> None:
    """After a learn with nothing waiting the worker counts the labels (``_Worker.idle``);
    the next prediction uses them unchanged and equals one that counted them itself."""
    from roger_daemon.daemon.worker import _Worker
    from roger_daemon.learner import RogerParams

    def load() -> _Worker:
        w = _Worker()
        w.handle({"op": "load", "robot": "aibo", "x_dim": STREAM.x.shape[1],
                  "y_dim": STREAM.y.shape[1], "model": "roger", "seed": 0,
                  "params": RogerParams().to_mapping(), "state": None, "codes": None})
        return w

    ahead, plain = load(), load()
    vocab = list(LABELS)
    for t in range(40):
        for w in (ahead, plain):
            req = {"op": "learn", "x": STREAM.x[t].tobytes(), "y": STREAM.y[t].tobytes(),
                   "code": int(STREAM.labels[t]), "tick": t}
            if t == 0:
                req["vocab"] = vocab  # sent with the first learn request, then when it grows
            assert w.handle(req)["ok"]
        ahead.idle()
        assert ahead.rt._labels_cache[0] == ahead.rt.generation  # counted now
        assert plain.rt._labels_cache is None or plain.rt._labels_cache[0] != plain.rt.generation
        if t % 10 == 9:
            got = [decode("prediction", w.handle({"op": "predict", "x": STREAM.x[t].tobytes(),
                                                  "tick": t, "t": t / 30, "vocab": vocab})["pred"],
                          dims=ahead.rt.dims, robot="aibo") for w in (ahead, plain)]
            _same_prediction(got[0], got[1])  # type: ignore[arg-type]
            assert any(e.label for e in got[0].multimap)  # type: ignore[union-attr]
