"""``roger demo`` (``make demo``): daemon, simulator, HCC demonstrator, then the HCC
transitioner on the learned experts, as separate processes over Zenoh; a summary at the end."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from roger_daemon.recording import read_timeline

pytestmark = pytest.mark.integration

ROGER = [sys.executable, "-m", "roger_daemon"]


def _tails(out: Path, lines: int = 8) -> str:
    """The last lines of every log and stats file the demo wrote (what a hung stage did)."""
    files = sorted([*out.rglob("*.log"), *out.rglob("*.json")])
    return "".join(f"--- {f.relative_to(out)}\n" + "\n".join(
        f.read_text(errors="replace").splitlines()[-lines:]) + "\n"
        for f in files if "wal" not in f.parts)


def _demo(out: Path, *extra: str, timeout: float = 240.0) -> tuple[dict[str, Any], str, float]:
    t0 = time.monotonic()
    # its own process group: a demo past the timeout is stopped with every process it started
    # (subprocess.run's kill reached the demo only; its last daemon ran on for half an hour)
    proc = subprocess.Popen([*ROGER, "demo", "--out", str(out), *extra], text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            start_new_session=True)
    try:
        stdout, stderr = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.terminate()  # the demo stops its children on SIGTERM
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.communicate(timeout=30)
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        raise AssertionError(f"roger demo still ran after {timeout} s; its logs:\n"
                             + _tails(out)) from None
    wall = time.monotonic() - t0
    assert proc.returncode == 0, stdout[-4000:] + stderr[-4000:]
    return json.loads((out / "summary.json").read_text()), stdout, wall


def _check(summary: dict[str, Any], stdout: str, locations: list[int]) -> None:
    assert [e["location"] for e in summary["demonstrations"]] == locations
    ticks = sum(e["ticks"] for e in summary["demonstrations"])
    # the daemon learned every demonstrated tick, live, and the log holds the same pairs
    assert summary["pairs"] == ticks
    tl = read_timeline([Path(p) for p in summary["mcap"]])
    assert len(tl.pairs) == ticks
    assert summary["experts"] >= 1 and len(summary["expert_labels"]) == summary["experts"]
    test = summary["test_episode"]
    assert test["outcome"] in ("goal", "own_goal", "out", "timeout")
    # the transitioner was served a prediction for every tick of its episode
    tr = summary["transitioner"]
    assert tr["no_prediction"] == 0 and tr["commands"] == test["ticks"]
    assert Path(summary["checkpoint"]).is_file()
    for f in summary["figures"].values():
        assert Path(f).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "roger demo: summary" in stdout and "experts found" in stdout
    # the experts merged per group: a checkpoint written by `roger replay --merge-groups`,
    # served by a second daemon (it resumed it, in predict mode), one episode per location
    merged = summary["merged"]
    assert merged["experts"] == len(set(summary["expert_labels"].values()))
    assert Path(merged["checkpoint_dir"], "aibo").is_dir()
    assert merged["command"].startswith("roger replay ") and "--merge-groups" in merged["command"]
    assert [e["location"] for e in merged["episodes"]] == locations
    assert merged["transitioner"]["no_prediction"] == 0
    assert merged["transitioner"]["commands"] == sum(e["ticks"] for e in merged["episodes"])
    served = Path(summary["checkpoint"]).parents[2] / "daemon-merged.log"
    assert "resumed from" in served.read_text() and "(predict," in served.read_text()
    assert f"merged:     {merged['command']}" in stdout
    # the robot alone: roger play on the live daemon's learned transitions, no HCC process
    auto = summary["autonomous"]
    assert [e["location"] for e in auto["episodes"]] == locations
    assert auto["attempts"] == len(locations) and 0 <= auto["goals"] <= auto["attempts"]
    ctl = auto["controller"]
    assert ctl["role"] == "play" and ctl["no_prediction"] == 0
    assert ctl["learned"] == sum(e["ticks"] for e in auto["episodes"]) == ctl["commands"]
    assert not list(Path(summary["checkpoint"]).parents[2].glob("play/*hcc*"))
    assert f"{auto['goals']} goals of {auto['attempts']} attempts" in stdout
    assert "roger play --checkpoint" in stdout and "roger model fsm" in stdout


def test_short_demo(tmp_path: Path) -> None:
    from roger_daemon.harness import free_port

    daemon_port, sim_port = free_port(), free_port()  # issue 56, item 17: ports of one's own
    summary, stdout, _ = _demo(tmp_path / "demo", "--locations", "0", "--vision", "fast",
                               "--episode-duration", "6", "--daemon-port", str(daemon_port),
                               "--sim-port", str(sim_port))
    _check(summary, stdout, [0])
    for name in ("daemon", "daemon-merged", "daemon-play"):  # every daemon of the demo
        config = (tmp_path / "demo" / f"{name}.toml").read_text(encoding="utf-8")
        assert f"tcp/127.0.0.1:{daemon_port}" in config, name
    assert summary["test_episode"]["sim_time_s"] <= 6.0 + 1e-6


@pytest.mark.slow
def test_default_demo(tmp_path: Path) -> None:
    summary, stdout, _ = _demo(tmp_path / "demo", timeout=900.0)
    _check(summary, stdout, [0, 1, 3, 6])
