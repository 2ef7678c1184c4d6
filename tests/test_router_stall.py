"""A router forwards realtime traffic while a BLOCK burst waits on a busy subscriber (issue 55).

A real ``roger router`` on 127.0.0.1 (scouting off), a subscriber that takes 50 ms per sample,
a publisher of express BLOCK bursts to it, and a 30 Hz DROP stream through the same router
(tests/zenoh_stall_roles.py). On Zenoh's one-thread runtime the router's only worker waited
inside each BLOCK burst until Zenoh gave up on the slow link (5 s), forwarding nothing else:
about half of the realtime samples were lost and the longest gap was 5.1 s. On Zenoh's
multi-thread runtime (docs/zenoh-notes.md §1.3) every sample arrives, the longest gap 0.1 s.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from roger_daemon.harness import free_port
from tests.test_router import Router

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[1]
ROLES = Path(__file__).with_name("zenoh_stall_roles.py")
SECONDS = 8.0  # bursts at 0, 2, 4, 6 s: a stalled router's 5 s gap fits


def _role(role: str, endpoint: str, seconds: float) -> subprocess.Popen[str]:
    env = {k: v for k, v in os.environ.items() if k != "ZENOH_RUNTIME"}
    env["RUST_LOG"] = "error"
    return subprocess.Popen([sys.executable, str(ROLES), role, endpoint, str(seconds)],
                            cwd=ROOT, env=env, stdout=subprocess.PIPE, text=True)


def test_a_block_burst_to_a_busy_subscriber_does_not_stall_the_router(tmp_path: Path,
                                                                    monkeypatch: pytest.MonkeyPatch
                                                                    ) -> None:
    monkeypatch.delenv("ZENOH_RUNTIME", raising=False)  # the router's runtime is ROGER's choice
    port = free_port()
    router = Router(ROOT / "configs/zenoh/router.json5", port, tmp_path / "router.log")
    endpoint = f"tcp/127.0.0.1:{port}"
    procs = []
    try:
        procs = [_role("slow", endpoint, SECONDS + 4), _role("block", endpoint, SECONDS)]
        rt = _role("realtime", endpoint, SECONDS)
        out, _ = rt.communicate(timeout=120)
        for p in procs:
            p.communicate(timeout=120)
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
        router.stop()
    report = json.loads(out.strip().splitlines()[-1])
    sent, got = report["sent"], report["got"]
    assert sent > 150  # the stream ran (30 Hz for 8 s: ~240)
    # generous margins: a stalled router lost ~50 % and went 5 s without delivering
    assert got >= 0.9 * sent, report
    assert report["max_gap_s"] < 2.5, report


def test_the_simulator_publishes_nothing_with_block(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every publisher of ``roger sim`` (perceptions and episode events, the final one
    included) is DROP: a BLOCK sample waiting in a router for a busy subscriber held the
    perceptions behind it (docs/zenoh-notes.md §4.1). The episode events have a priority of
    their own."""
    import argparse

    import zenoh

    from simulator.sim_args import configure, sim_config
    from simulator.sim_node import SimNode
    from simulator.transport import StopFlag, loopback_config, open_session

    parser = argparse.ArgumentParser()
    configure(parser)
    args = parser.parse_args(["--max-episodes", "1", "--wait-subscribers", "0"])
    stop = StopFlag(install=False)
    stop.stopped = True  # no episode: declare, publish the final event, leave
    node = SimNode(args, sim_config(args), stop)
    declared: list[zenoh.Publisher] = []
    with open_session(loopback_config()) as session:
        real = session.declare_publisher

        class Spy:
            def __getattr__(self, name: str) -> object:
                return getattr(session, name)

            def declare_publisher(self, *a: object, **kw: object) -> zenoh.Publisher:
                pub = real(*a, **kw)  # type: ignore[arg-type]
                declared.append(pub)
                return pub

        try:
            node.run(Spy())
        finally:
            node.sim.close()
        kinds = {str(p.key_expr).rsplit("/", 1)[-1]: p for p in declared}
        assert set(kinds) >= {"perception", "episode"}
        assert all(p.congestion_control == zenoh.CongestionControl.DROP for p in declared)
        assert kinds["episode"].priority == zenoh.Priority.INTERACTIVE_HIGH
