"""Crash test with real processes: ``roger daemon`` (lockstep, recording on) is killed with
SIGKILL in the middle of a learning session, twice; each restart recovers the footer-less log
and resumes from the last checkpoint plus the replayed log tail. The final model equals,
behaviourally, the model of the same session run without a crash: no training sample lost.

Real Zenoh on 127.0.0.1 (multicast scouting off, a free port per daemon life); the client
plays robot and demonstrator with the synthetic two-branch stream. After the second kill (at
an arbitrary moment, so the last flush interval of log may be gone) the client resumes sending
after the daemon's reported ``last_learned_tick``, as a robot would.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from daemon_sessions import synthetic_stream

from protocols.messages import Dims
from roger_daemon.config import load_config
from roger_daemon.daemon.checkpoint import list_checkpoints, read_checkpoint
from roger_daemon.daemon.main import make_model
from roger_daemon.labels import majority_labels as plain_majority_labels
from roger_daemon.labels import majority_labels_coded as majority_labels
from roger_daemon.learner import load_model
from roger_daemon.recording import LogReader, is_complete, list_session_files
from roger_daemon.replay.compare import REL_TOL, behaviour, behaviour_differences

harness = pytest.importorskip("roger_daemon.harness")

pytestmark = pytest.mark.integration

N = 300
X, Y, LABELS = synthetic_stream("sqrt", N)
PROBES = [[v] for v in np.linspace(0.0, 1.0, 11)]
DIMS = Dims(1, 1)


def _config(workdir: Path, port: int) -> Path:
    workdir.mkdir(parents=True, exist_ok=True)
    return harness.write_config(
        workdir / f"daemon-{port}.toml", port=port, workdir=workdir,
        daemon={"clock": "lockstep", "seed": 3},
        checkpoint={"every_updates": 0, "every_s": 0.0},
        recording={"enabled": True},
        robots=[{"id": "sim", "x_dim": 1, "y_dim": 1}],
    )


class Life:
    """One daemon process and a client connected to it."""

    def __init__(self, workdir: Path, *args: str) -> None:
        self.port = harness.free_port()
        self.config = _config(workdir, self.port)
        self.daemon = harness.DaemonProcess(self.config, args=args)
        self.client: Any = None
        try:
            self.daemon.wait_ready()
            self.client = harness.Client(f"tcp/127.0.0.1:{self.port}", robot="sim", dims=DIMS)
            self.client.wait_daemon()
        except BaseException:
            self.close()
            raise

    def feed(self, ticks: range) -> None:
        for t in ticks:
            self.client.perception(t, X[t])
            self.client.action(t, Y[t], LABELS[t])
            self.client.wait_prediction(t)

    def status(self) -> Any:
        return self.client.wait_status()

    def close(self) -> None:
        if self.client is not None:
            self.client.close()
            self.client = None
        self.daemon.kill()


def _logged_action_ticks(path: Path) -> set[int]:
    """Ticks of the actions a (possibly footer-less) log holds on disk now."""
    return {lm.message.sequence for lm in LogReader(path).messages()
            if lm.topic == "roger/sim/action"}


def _wait_logged(recordings: Path, tick: int, timeout: float = 60.0) -> Path:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        files = list_session_files(recordings, robot="sim")
        if files and tick in _logged_action_ticks(files[-1].path):
            return files[-1].path
        time.sleep(0.1)
    raise TimeoutError(f"action {tick} not flushed to the log within {timeout} s")


def _final_model(workdir: Path) -> tuple[Any, dict[int, str], dict[str, Any]]:
    ck = read_checkpoint(list_checkpoints(workdir / "checkpoints", "sim")[0])
    model = load_model(ck.model)
    vocab = [str(v) for v in ck.daemon["label_vocab"].tolist()]
    labels = majority_labels(np.asarray(model.assignments()), ck.daemon["label_codes"], vocab)
    return model, labels, ck.meta


def test_sigkill_twice_then_recovery_equals_the_uninterrupted_session(tmp_path: Path) -> None:
    # -- the same session without a crash: the daemon's model, learned in this process (the
    # point here is the crashes; that a daemon learns what this learner learns is
    # tests/test_workers.py's and tests/test_replay_daemon.py's)
    ref_config = _config(tmp_path / "reference", harness.free_port())
    ref_model = make_model(load_config(ref_config).robots[0])
    for t in range(N):
        ref_model.learn_one(X[t], Y[t])
    ref_labels = plain_majority_labels(np.asarray(ref_model.assignments()), LABELS)
    assert ref_model.n_experts >= 2

    # -- life 1: learn 130 pairs (a checkpoint at 100), SIGKILL once they are all logged ---
    work = tmp_path / "crash"
    recordings = work / "recordings"
    one = Life(work)
    try:
        one.feed(range(100))
        one.client.wait_status(lambda s: s.updates == 100 and s.queue_depth == 0)
        one.client.control("checkpoint")
        one.client.wait_status(lambda s: s.info["checkpoint_updates"] == 100)
        one.feed(range(100, 130))
        log1 = _wait_logged(recordings, 129)
        one.daemon.proc.kill()
        one.daemon.proc.wait(10)
    finally:
        one.close()
    assert not is_complete(log1)
    assert read_checkpoint(list_checkpoints(work / "checkpoints", "sim")[0]).meta.updates == 100

    # -- life 2: recovers 30 pairs from the log, goes on, SIGKILL at an arbitrary moment ----
    two = Life(work)
    try:
        text = two.daemon.log()
        assert f"log {log1} had no footer" in text and "recovered in place" in text
        assert "re-learned 30 pairs (ticks 100..129)" in text
        st = two.status()
        assert st.updates == 130 and st.info["last_learned_tick"] == 129
        assert st.info["recovered_pairs"] == 30
        two.feed(range(130, 220))
        two.daemon.proc.kill()  # no waiting: the last flush interval of log may be lost
        two.daemon.proc.wait(10)
    finally:
        two.close()
    assert is_complete(log1)  # recovered in place by life 2

    # -- life 3: a broken file among the logs is reported and skipped ------------------------
    garbage = recordings / "roger-sim-20000101T000000Z.mcap"
    garbage.write_bytes(b"\x89MCAP0\r\n" + bytes(64))
    three = Life(work)
    try:
        text = three.daemon.log()
        assert f"{garbage} is not usable" in text
        st = three.status()
        resume = int(st.info["last_learned_tick"]) + 1
        assert st.updates == resume and 130 <= resume <= 220
        three.feed(range(resume, N))
        code, _ = three.daemon.terminate()
        assert code == 0, three.daemon.log()
    finally:
        three.close()

    model, labels, meta = _final_model(work)
    assert meta.updates == N
    diffs = behaviour_differences(behaviour(model, PROBES), behaviour(ref_model, PROBES), REL_TOL)
    assert diffs == []
    assert labels == ref_labels

    # -- --fresh ignores both the checkpoints and the logs -----------------------------------
    four = Life(work, "--fresh")
    try:
        st = four.status()
        assert st.updates == 0 and st.info["recovered_pairs"] == 0
        assert "start-up recovery" not in four.daemon.log()
        assert four.daemon.terminate()[0] == 0
    finally:
        four.close()
