"""A full disk is a state, not a crash (docs/durability.md, *Disk full*).

A real daemon on a 5 MB tmpfs (``mount -t tmpfs``; skipped where mounting is not permitted)
with its checkpoints, write-ahead log and recordings there. The test fills the file system
while a lockstep sender feeds pairs: predictions go on, learning stops (and says so) before
the log could not take what is learned, status names the full path, the checkpoint failure
is logged a few times rather than at every loop cycle, and nothing is a traceback. Space
freed: learning resumes by itself. A restart then holds every pair ever acknowledged. A
daemon started on the full disk exits with status 75 and one line saying so.
"""

from __future__ import annotations

import contextlib
import errno
import os
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from protocols.messages import Dims
from roger_daemon.daemon.main import EXIT_DISK_FULL

harness = pytest.importorskip("roger_daemon.harness")

pytestmark = pytest.mark.integration

#: ~0.45 kB a record (16 floats and a label of the protocol's longest): with a reserve of
#: RESERVE_KB the log runs low after ~30-110 pairs (the default 1 MiB took ~1,700, 17 s);
#: the checkpoints stay small (they grow with x_dim squared)
X_DIM = 16
LABEL = ("seek-" * 52)[:256]
DIMS = Dims(X_DIM, 1)
RESERVE_KB = 64  # checkpoint.wal_reserve_kb's smallest


@pytest.fixture
def small_disk(tmp_path: Path) -> Iterator[Path]:
    """A 5 MB tmpfs of this test's own (skip if mounting is not permitted)."""
    mnt = tmp_path / "disk"
    mnt.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=5m", "tmpfs", str(mnt)],
                          capture_output=True, text=True, check=False)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({done.stderr.strip() or done.returncode})")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], check=False)


def _fill(where: Path) -> Path:
    """Write zeros into ``where/filler`` until the file system is full."""
    path = where / "filler"
    chunk = bytes(64 << 10)
    with open(path, "wb", buffering=0) as f:
        with contextlib.suppress(OSError):
            while True:
                f.write(chunk)
        while True:  # the last few bytes
            try:
                if not f.write(b"\0" * 512):
                    break
            except OSError as exc:
                assert exc.errno == errno.ENOSPC
                break
    assert os.statvfs(where).f_bavail == 0
    return path


def _config(tmp_path: Path, disk: Path, port: int) -> Path:
    return harness.write_config(
        tmp_path / f"daemon-{port}.toml", port=port, workdir=disk,  # its log: outside
        # status at 20 Hz: the test waits for a fresh one every 10 pairs (at 1 Hz each wait
        # took up to a second, half of the test's time)
        daemon={"clock": "lockstep", "seed": 3, "status_hz": 20},
        checkpoint={"every_updates": 100, "every_s": 0.0, "keep": 2,
                    "wal_reserve_kb": RESERVE_KB},
        # the recordings elsewhere: the space freed is then the filler's, and the final
        # checkpoint fits (with them on the small disk it may not: exit status 75)
        recording={"enabled": True, "dir": str(tmp_path / "recordings")},
        robots=[{"id": "sim", "x_dim": X_DIM, "y_dim": 1}],
    )


class Sender:
    """Lockstep pairs: action(t), perception(t), wait for prediction(t)."""

    def __init__(self, client: Any) -> None:
        self.client = client
        self.rng = np.random.default_rng(0)
        self.t = 0

    def pair(self) -> int:
        x = self.rng.uniform(0.0, 1.0, X_DIM)
        self.client.action(self.t, np.array([x.mean()]), LABEL)
        self.client.perception(self.t, x)
        updates = int(self.client.wait_prediction(self.t, timeout=60).updates)
        self.t += 1
        return updates


def _daemon(cfg: Path) -> tuple[Any, Any]:
    proc = harness.DaemonProcess(cfg)
    proc.wait_ready()
    port = int(cfg.stem.split("-")[1])
    client = harness.Client(f"tcp/127.0.0.1:{port}", robot="sim", dims=DIMS)
    client.wait_daemon(30)
    return proc, client


def test_a_full_disk_stops_learning_not_the_daemon_and_space_resumes_it(
        tmp_path: Path, small_disk: Path) -> None:
    cfg = _config(tmp_path, small_disk, harness.free_port())
    proc, client = _daemon(cfg)
    try:
        s = Sender(client)
        acked = max(s.pair() for _ in range(20))
        assert acked == 20
        filler = _fill(small_disk)
        status: Any = None
        for _ in range(1000):  # the log's reserve: ~30-110 pairs of this size
            acked = max(acked, s.pair())
            if s.t % 10 == 0:
                status = client.wait_status()
                if status.info["learning_stopped"]:
                    break
        assert status is not None and status.info["learning_stopped"], status
        assert str(small_disk) in status.info["disk_full"]
        assert status.info["level"] == "ERROR" and "learning stopped" in \
            status.info["level_reasons"]
        stopped_at = status.updates
        for _ in range(20):  # predictions go on, nothing more is learned
            assert s.pair() == stopped_at
        assert proc.proc.poll() is None
        filler.unlink()
        for _ in range(1200):  # the log retries once a second: waited for up to a minute
            if s.pair() > stopped_at:
                break
            time.sleep(0.05)
        after = s.pair()
        assert after > stopped_at
        acked = max(acked, after)
        code, _ = proc.terminate(timeout=60)
        assert code == 0, proc.log()
    finally:
        client.close()
        proc.kill()
    out = proc.log()
    assert "Traceback" not in out, out
    assert out.count("checkpoint failed") <= 10, out
    assert "learning stopped at tick" in out and "learning resumed at tick" in out
    proc2, client2 = _daemon(cfg)  # a new life holds every pair acknowledged
    try:
        assert client2.wait_status().updates >= acked
    finally:
        client2.close()
        proc2.kill()


def test_a_start_on_a_full_disk_exits_75_with_one_line(tmp_path: Path,
                                                       small_disk: Path) -> None:
    cfg = _config(tmp_path, small_disk, harness.free_port())
    _fill(small_disk)
    proc = harness.DaemonProcess(cfg)
    code = proc.proc.wait(120)
    proc.kill()
    out = proc.log()
    assert code == EXIT_DISK_FULL == 75, out
    assert "Traceback" not in out, out
    assert "cannot start: the disk is full" in out and str(small_disk) in out, out
