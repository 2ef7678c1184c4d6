"""``roger up``: one launch file starts a demonstration session; Ctrl-C stops it cleanly."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import pytest

from roger_daemon.console import UsageError
from roger_daemon.harness import Client, free_port, interruptible_child
from simulator.launch import plan

pytestmark = pytest.mark.integration


def test_plan_sizes_the_queue_and_wires_the_ports(tmp_path: Path) -> None:
    data = {"ports": {"daemon": 17447, "sim": 17450},
            "sim": {"locations": "0,1", "time_limit": 10.0, "episodes_per_location": 2}}
    p = plan(data, tmp_path)
    assert p.max_pairs == 2 * 2 * 10 * 30 and p.queue_size == p.max_pairs and not p.warnings
    assert "--set" in p.argv["daemon"] and f"daemon.queue_size={p.max_pairs}" in p.argv["daemon"]
    assert 'zenoh.listen=["tcp/127.0.0.1:17447"]' in p.argv["daemon"]
    ctl, sim = p.argv["controller"], p.argv["sim"]
    assert ctl[ctl.index("--role") + 1] == "demonstrator"
    assert "tcp/127.0.0.1:17450" in ctl and "tcp/127.0.0.1:17447" in ctl
    assert sim[sim.index("--listen") + 1] == "tcp/127.0.0.1:17450"
    # a queue set too small is kept, with a warning
    small = plan({**data, "daemon": {"queue_size": 100}}, tmp_path)
    assert small.queue_size == 100 and "pairs will be dropped" in small.warnings[0]


@pytest.mark.parametrize("data, message", [
    ({"controller": {"role": "pilot"}}, "controller.role must be one of demonstrator"),
    ({"ports": {"daemon": "x"}}, "ports.daemon must be int, got 'x'"),
    ({"sim": {"time_limit": -1}}, "sim.time_limit must be > 0"),
    ({"robots": {}}, "unknown table(s) ['robots']"),
])
def test_plan_rejects_a_bad_file(tmp_path: Path, data: dict, message: str) -> None:
    with pytest.raises(UsageError, match=message.replace("(", r"\(").replace(")", r"\)")
                       .replace("[", r"\[").replace("]", r"\]")):
        plan(data, tmp_path)


@pytest.mark.slow  # ~12 s: three processes and a live session (make test-all)
def test_up_runs_a_demonstration_and_stops_cleanly_on_ctrl_c(tmp_path: Path) -> None:
    port = free_port()
    launch = tmp_path / "up.toml"
    launch.write_text(f"""
[session]
dir = "{tmp_path / 'run'}"
[ports]
daemon = {port}
sim = 0
[sim]
locations = "all"
time_limit = 150.0
args = ["--vision", "fast"]
""", encoding="utf-8")
    with interruptible_child():  # it is sent SIGINT below
        proc = subprocess.Popen([sys.executable, "-m", "roger_daemon", "up", str(launch)],
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    client = None
    try:
        client = Client(f"tcp/127.0.0.1:{port}")
        client.wait_daemon(120)
        st = client.wait_status(lambda s: s.updates > 0, 120)  # learning from the HCC
        assert st.mode == "learn+predict" and st.dropped == 0
        proc.send_signal(signal.SIGINT)  # what a terminal's Ctrl-C delivers to `roger up`
        out, _ = proc.communicate(timeout=120)
    finally:
        if client is not None:
            client.close()
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 130, out  # interrupted, as every command after Ctrl-C (issue 56)
    assert "stopped cleanly (SIGINT)" in out and "Traceback" not in out
    for name in ("sim", "controller", "daemon"):
        assert f"{name} exited with 0" in out
    run = tmp_path / "run"
    assert list((run / "checkpoints" / "aibo").glob("ckpt-*.npz"))  # the final checkpoint
    assert list((run / "recordings").rglob("*.mcap"))
    assert "checkpoint" in (run / "daemon.log").read_text()
