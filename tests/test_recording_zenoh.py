"""`roger record` and `roger replay --publish` as real processes over Zenoh on 127.0.0.1.

Subprocesses are started before this process opens its Zenoh session (never fork after open);
every session is closed; multicast scouting is off and ports are free ephemeral ones.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from protocols import Action, Perception, encode, keys
from roger_daemon.harness import free_port
from roger_daemon.recording import is_complete, read_metadata
from roger_daemon.recording.mcapio import LogReader

zenoh = pytest.importorskip("zenoh")

pytestmark = pytest.mark.integration


def _config(*, listen: list[str], connect: list[str]):  # type: ignore[no-untyped-def]
    from roger_daemon.recording.zenoh_net import make_config

    return make_config(listen=listen, connect=connect)


def _wait(cond, timeout: float, what: str) -> None:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            pytest.fail(f"timed out waiting for {what}")
        time.sleep(0.02)


def test_roger_record_records_published_messages_and_finishes_on_sigterm(
    tmp_path: Path,
) -> None:
    port = free_port()
    err = open(tmp_path / "stderr.txt", "w")  # closed below
    proc = subprocess.Popen(
        [sys.executable, "-m", "roger_daemon", "record", "--key", "roger/**", "--out",
         str(tmp_path / "logs"), "--listen", f"tcp/127.0.0.1:{port}", "--connect", "none",
         "--flush-interval", "0.1"],
        stdout=subprocess.PIPE, stderr=err, text=True,
    )
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert line.startswith("recording roger/** -> "), line
        path = Path(line.split(" -> ", 1)[1].strip())
        sent: list[tuple[str, bytes, int, int]] = []
        with zenoh.open(_config(listen=[], connect=[f"tcp/127.0.0.1:{port}"])) as s:
            pubs = {k: s.declare_publisher(k) for k in (keys.perception("aibo"),
                                                       keys.action("aibo"))}
            _wait(lambda: all(p.matching_status for p in pubs.values()), 20, "the recorder")
            for t in range(40):
                stamp = time.time_ns()
                for key, payload in (
                    (keys.perception("aibo"),
                     encode(Perception("aibo", t, t / 30, x=np.full(23, t), stamp_ns=stamp))),
                    (keys.action("aibo"),
                     encode(Action("aibo", t, t / 30, y=np.full(9, t), label="seek",
                                   stamp_ns=stamp))),
                ):
                    pubs[key].put(payload)
                    sent.append((key, payload, t, stamp))
            _wait(lambda: sum(1 for _ in LogReader(path).messages()) >= len(sent), 20,
                  "the messages to reach the file")
            for p in pubs.values():
                p.undeclare()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=120) == 0
    finally:
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait()
        if proc.stdout is not None:
            proc.stdout.close()
        err.close()
    assert is_complete(path)
    got = [(lm.topic, lm.message.data, lm.message.sequence, lm.message.publish_time)
           for lm in LogReader(path).messages()]
    assert sorted(got) == sorted(sent)
    for key in (keys.perception("aibo"), keys.action("aibo")):  # per-key order kept
        assert [g for g in got if g[0] == key] == [x for x in sent if x[0] == key]
    meta = read_metadata(path)
    assert meta["created_by"] == "roger record" and meta["record_key"] == "roger/**"
    assert path.name.startswith("roger-all-")


def test_replay_publish_resends_the_recorded_inputs(tmp_path: Path) -> None:
    from daemon_sessions import record_session

    s = record_session(tmp_path / "logs", n_ticks=30, modes={10: "learn+predict"})
    inputs = [(lm.topic, lm.message.data) for lm in LogReader(s.paths[0]).messages()
              if lm.topic.rsplit("/", 1)[1] in ("perception", "action", "control")]
    port = free_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "roger_daemon", "replay", str(s.paths[0]), "--publish",
         "--speed", "0", "--connect", f"tcp/127.0.0.1:{port}", "--listen", "none",
         "--wait", "20", "--json"],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
    )
    got: list[tuple[str, bytes]] = []
    try:
        with zenoh.open(_config(listen=[f"tcp/127.0.0.1:{port}"], connect=[])) as zs:
            sub = zs.declare_subscriber("roger/**", zenoh.handlers.FifoChannel(4096))

            def drained() -> bool:
                while (smp := sub.try_recv()) is not None:
                    got.append((str(smp.key_expr), smp.payload.to_bytes()))
                return len(got) >= len(inputs)

            _wait(drained, 30, "the re-published messages")
            sub.undeclare()
        out, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 0
    assert json.loads(out)["published"] == len(inputs)
    for key in {k for k, _ in inputs}:
        assert [g for g in got if g[0] == key] == [i for i in inputs if i[0] == key]
