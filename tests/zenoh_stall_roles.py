"""The processes of the router-stall test (``tests/test_router_stall.py``), one role per run.

``python tests/zenoh_stall_roles.py ROLE ENDPOINT SECONDS``, every role a Zenoh client of the
router at ENDPOINT (``roger_daemon.zenoh_session.open_session``, as every ROGER process):

* ``slow``: subscribes to the BLOCK key and takes 50 ms per sample (a busy peer);
* ``block``: publishes bursts of 300 express BLOCK samples of 8 kB on that key, every 2 s
  (the simulator's episode events were published so until issue 55);
* ``realtime``: publishes 30 Hz DROP samples (a robot's perceptions) from one session and
  receives them in another, through the router; prints ``{"sent", "got", "max_gap_s"}``.
"""

from __future__ import annotations

import json
import os
import sys
import time

import zenoh

from roger_daemon.zenoh_session import ZenohSettings, open_session

BLOCK_KEY = "stall/block"
REALTIME_KEY = "stall/realtime"


def _session(endpoint: str) -> zenoh.Session:
    return open_session(ZenohSettings(mode="client", connect=(endpoint,), listen=None))


def slow(endpoint: str, seconds: float) -> dict[str, int]:
    got = [0]

    def busy(_sample: zenoh.Sample) -> None:
        got[0] += 1
        time.sleep(0.05)

    s = _session(endpoint)  # not closed: closing would first run every queued callback
    s.declare_subscriber(BLOCK_KEY, busy)
    time.sleep(seconds)
    return {"got": got[0]}


def block(endpoint: str, seconds: float) -> dict[str, int]:
    with _session(endpoint) as s:
        pub = s.declare_publisher(BLOCK_KEY, congestion_control=zenoh.CongestionControl.BLOCK,
                                  express=True)
        sent, payload = 0, bytes(8000)
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            for _ in range(300):
                pub.put(payload)
                sent += 1
            time.sleep(2.0)
    return {"sent": sent}


def realtime(endpoint: str, seconds: float) -> dict[str, float]:
    arrivals: list[float] = []
    with _session(endpoint) as tx, _session(endpoint) as rx:
        rx.declare_subscriber(REALTIME_KEY, lambda _s: arrivals.append(time.monotonic()))
        pub = tx.declare_publisher(REALTIME_KEY, express=True)
        time.sleep(1.0)  # the subscription reaches the router
        sent = 0
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            pub.put(b"x" * 100)
            sent += 1
            time.sleep(1 / 30)
        time.sleep(1.0)
    gaps = [b - a for a, b in zip(arrivals, arrivals[1:], strict=False)]
    return {"sent": sent, "got": len(arrivals), "max_gap_s": max(gaps, default=float("inf"))}


if __name__ == "__main__":
    role, ep, secs = sys.argv[1], sys.argv[2], float(sys.argv[3])
    run = {"slow": slow, "block": block, "realtime": realtime}[role]
    print(json.dumps(run(ep, secs)), flush=True)
    os._exit(0)  # at once: the slow subscriber's backlog of callbacks is not worth waiting for
