"""``roger bench`` stopped by SIGTERM stops the daemon it started (real subprocesses).

The benchmarks start a real ``roger daemon``; SIGTERM's default action would end the bench at
once and leave that daemon running. ``roger_daemon.console.exit_on_sigterm`` turns it into
``SystemExit(143)``, so the bench's ``finally`` blocks stop the daemon first.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

from process_testing import processes_naming


def test_sigterm_to_a_bench_stops_its_daemon(tmp_path: Path) -> None:
    keep = tmp_path / "keep"
    config = str(keep / "soak.toml")  # named on the daemon's command line only
    proc = subprocess.Popen(
        [sys.executable, "-m", "roger_daemon", "bench", "soak", "--minutes", "5",
         "--interval", "1", "--keep", str(keep), "--json"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        end = time.monotonic() + 240
        while not processes_naming(config):
            assert proc.poll() is None and time.monotonic() < end, "no daemon started"
            time.sleep(0.1)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(240) == 143
    finally:
        if proc.poll() is None:
            proc.kill()
    assert processes_naming(config) == []

