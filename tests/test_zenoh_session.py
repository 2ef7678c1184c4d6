"""One owner of Zenoh session setup: flags, layering (file, flags, overrides), real sessions."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import pytest

from roger_daemon.config import parse_config
from roger_daemon.console import UsageError
from roger_daemon.harness import free_port
from roger_daemon.zenoh_session import (
    ZenohOverrideError,
    ZenohSettings,
    add_zenoh_args,
    endpoints,
    open_session,
    settings_from_args,
    zenoh_config,
)


def _parse(*argv: str, **defaults: object) -> ZenohSettings:
    parser = argparse.ArgumentParser()
    add_zenoh_args(parser, **defaults)  # type: ignore[arg-type]
    return settings_from_args(parser.parse_args(list(argv)))


def _get(cfg: object, key: str) -> object:
    return json.loads(cfg.get_json(key))  # type: ignore[attr-defined]


def test_endpoint_flags_take_comma_lists_and_none() -> None:
    assert endpoints(["tcp/127.0.0.1:1,tcp/127.0.0.1:2", " tcp/127.0.0.1:3 "]) == (
        "tcp/127.0.0.1:1", "tcp/127.0.0.1:2", "tcp/127.0.0.1:3")
    assert endpoints(["none"]) == () and endpoints(["NONE", ""]) == ()


def test_without_a_file_the_commands_defaults_apply_and_flags_override_them() -> None:
    s = _parse(listen=("tcp/127.0.0.1:0",), connect=("tcp/127.0.0.1:7447",), lease_ms=2000,
               gossip=True)
    assert s == ZenohSettings(mode="peer", listen=("tcp/127.0.0.1:0",),
                              connect=("tcp/127.0.0.1:7447",), multicast_scouting=False,
                              lease_ms=2000, gossip=True)
    s = _parse("--connect", "none", "--listen", "tcp/127.0.0.1:9", listen=("tcp/127.0.0.1:0",),
               connect=("tcp/127.0.0.1:7447",))
    assert s.connect == () and s.listen == ("tcp/127.0.0.1:9",)


def test_a_file_is_overridden_only_by_the_flags_given(tmp_path: Path) -> None:
    f = tmp_path / "z.json5"
    f.write_text('{ mode: "client", connect: { endpoints: ["tcp/127.0.0.1:1"] },'
                 ' listen: { endpoints: ["tcp/127.0.0.1:2"] } }')
    s = _parse("--zenoh-config", str(f), "--connect", "tcp/127.0.0.1:3",
               "--zenoh-set", "transport/link/tx/lease=1500",
               listen=("tcp/127.0.0.1:0",), connect=("tcp/127.0.0.1:7447",), gossip=True)
    assert (s.config_file, s.mode, s.listen, s.multicast_scouting, s.gossip) == (
        f, None, None, None, None)
    cfg = zenoh_config(s)
    # file, then flags, then overrides
    assert _get(cfg, "mode") == "client"
    assert _get(cfg, "listen/endpoints") == ["tcp/127.0.0.1:2"]
    assert _get(cfg, "connect/endpoints") == ["tcp/127.0.0.1:3"]
    assert _get(cfg, "transport/link/tx/lease") == 1500


def test_bad_files_and_overrides_are_usage_errors(tmp_path: Path) -> None:
    with pytest.raises(UsageError, match="no such file"):
        _parse("--zenoh-config", str(tmp_path / "missing.json5"))
    with pytest.raises(UsageError, match="KEY=JSON5"):
        _parse("--zenoh-set", "transport/link/tx/lease")
    with pytest.raises(ZenohOverrideError, match="no/such/key"):
        zenoh_config(ZenohSettings(overrides=(("no/such/key", "1"),)))


@pytest.mark.integration
def test_sessions_on_loopback_exchange_samples_as_context_managers() -> None:
    ep = f"tcp/127.0.0.1:{free_port()}"
    got: list[bytes] = []
    with open_session(ZenohSettings(listen=(ep,))) as a, \
            open_session(ZenohSettings(listen=(), connect=(ep,))) as b:
        a.declare_subscriber("roger/test/**", lambda s: got.append(s.payload.to_bytes()))
        pub = b.declare_publisher("roger/test/x")
        end = time.monotonic() + 20
        while not got and time.monotonic() < end:
            pub.put(b"hello")
            time.sleep(0.05)
    assert got and got[0] == b"hello"


def test_realtime_send_queue_is_16_batches_unless_a_file_decides(tmp_path: Path) -> None:
    """Zenoh's 2 batches dropped predictions of a burst of robots (docs/zenoh-notes.md §4.3)."""
    key = "transport/link/tx/queue/size/real_time"
    assert _get(zenoh_config(_parse()), key) == 16
    f = tmp_path / "z.json5"
    f.write_text("{ transport: { link: { tx: { queue: { size: { real_time: 4 } } } } } }")
    assert _get(zenoh_config(_parse("--zenoh-config", str(f))), key) == 4
    g = tmp_path / "plain.json5"
    g.write_text('{ mode: "peer" }')
    assert _get(zenoh_config(_parse("--zenoh-config", str(g))), key) == 2  # Zenoh's default
    daemon = parse_config({"robots": [{"id": "a"}]})
    assert _get(zenoh_config(daemon.zenoh), key) == 16
    filed = parse_config({"robots": [{"id": "a"}], "zenoh": {"config_file": str(f)}})
    assert _get(zenoh_config(filed.zenoh), key) == 4


_THREADS_SCRIPT = """
import json, os, sys, time
from roger_daemon.harness import free_port
from roger_daemon.zenoh_session import ZenohSettings, open_session
ep = f"tcp/127.0.0.1:{free_port()}"
got = []
with open_session(ZenohSettings(listen=(ep,))) as a, \\
        open_session(ZenohSettings(listen=(), connect=(ep,))) as b:
    a.declare_subscriber("roger/test/**", lambda s: got.append(s.payload.to_bytes()))
    pub = b.declare_publisher("roger/test/x")
    end = time.monotonic() + 20
    while len(got) < 3 and time.monotonic() < end:
        pub.put(b"hello")
        time.sleep(0.05)
    names = sorted(open(f"/proc/self/task/{t}/comm").read().strip()
                   for t in os.listdir("/proc/self/task"))
print(json.dumps({"got": len(got), "threads": names,
                  "runtime": os.environ.get("ZENOH_RUNTIME")}))
"""


@pytest.mark.integration
@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="needs Linux's /proc")
@pytest.mark.parametrize("preset", [None, "(rx: (handover: app), tx: (handover: app))"])
def test_zenoh_keeps_its_own_runtimes_unless_the_environment_decides(
        preset: str | None) -> None:
    """``open_session`` leaves Zenoh on its multi-thread runtimes (docs/zenoh-notes.md §1.3,
    issue 55: on one thread a BLOCK sample stalled a router): two sessions of one process
    exchange samples with Zenoh's receive threads running and ``ZENOH_RUNTIME`` unset. A
    ``ZENOH_RUNTIME`` already in the environment is left as it is, and decides."""
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k != "ZENOH_RUNTIME"}
    if preset is not None:
        env["ZENOH_RUNTIME"] = preset
    out = subprocess.run([sys.executable, "-c", _THREADS_SCRIPT], env=env, check=True,
                         capture_output=True, text=True, timeout=120)
    report = json.loads(out.stdout.strip().splitlines()[-1])
    assert report["got"] >= 3
    runtime_threads = {n.split("-")[0] for n in report["threads"] if "-" in n}
    assert report["runtime"] == preset
    if preset is None:
        assert {"rx", "tx", "app"} <= runtime_threads
    else:
        assert "rx" not in runtime_threads and "tx" not in runtime_threads
