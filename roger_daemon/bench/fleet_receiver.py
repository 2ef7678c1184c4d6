"""The robots' receiving side of ``roger bench fleet``, in a process of its own (docs/fleet.md,
*Where a robot's predictions are received*).

In the realtime phase the bench's client process publishes every robot's perception and
action in one burst per tick; a prediction that reached that process during its own burst
could wait for the interpreter, so its receipt time could measure the client as well as the
daemon (in the runs where both processes received, docs/fleet.md found no difference).
A robot is a process (a machine) of its own: in that phase this process alone subscribes to
the robots' predictions and notes when each arrived (``time.monotonic_ns``: one clock for
every process of the machine), with nothing else to do.  (In the lockstep phase the feeding
process must answer each prediction, so it receives them itself, as before.)

Started by :func:`start`, it prints ``ready`` once subscribed, receives until its standard
input is closed, then writes what it received to ``--out`` (msgpack) and exits 0.

    python -m roger_daemon.bench.fleet_receiver --connect tcp/127.0.0.1:PORT --out FILE
"""

from __future__ import annotations

import argparse
import select
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import msgpack

__all__ = ["Receipts", "start", "stop"]

#: (received monotonic ns, key, payload) of every prediction, and the wall-clock minus
#: monotonic offset of the receiving process (the daemon stamps with the wall clock)
Receipts = tuple[list[tuple[int, str, bytes]], int]


def start(connect: str, out: Path, timeout: float = 120.0) -> subprocess.Popen[str]:
    """Start a receiver connected to ``connect``; return once it has subscribed."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "roger_daemon.bench.fleet_receiver", "--connect", connect,
         "--out", str(out)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    ready, _, _ = select.select([proc.stdout], [], [], timeout)
    line = proc.stdout.readline() if ready else ""  # "ready", or "" if it ended or hung
    if line.strip() != "ready":
        proc.kill()
        proc.wait(timeout)
        raise RuntimeError(f"the fleet receiver was not ready within {timeout:g} s "
                           f"(exit {proc.returncode})")
    return proc


def stop(proc: subprocess.Popen[str], out: Path, timeout: float = 120.0) -> Receipts:
    """Close the receiver's input, wait for it, and read what it received."""
    assert proc.stdin is not None
    proc.stdin.close()
    code = proc.wait(timeout)
    if code != 0:
        raise RuntimeError(f"the fleet receiver exited {code}")
    data = msgpack.unpackb(out.read_bytes())
    return [(int(t), str(k), bytes(p)) for t, k, p in data["raw"]], int(data["wall_to_mono"])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--connect", required=True)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    from protocols import keys
    from roger_daemon.zenoh_session import ZenohSettings, open_session

    raw: list[tuple[int, str, bytes]] = []

    def on_prediction(sample: Any) -> None:
        raw.append((time.monotonic_ns(), str(sample.key_expr), sample.payload.to_bytes()))

    wall_to_mono = time.time_ns() - time.monotonic_ns()
    with open_session(ZenohSettings(listen=(), connect=(args.connect,))) as session:
        subscriber = session.declare_subscriber(keys.all_of_kind("prediction"), on_prediction)
        print("ready", flush=True)
        sys.stdin.read()  # until the bench closes our input
        subscriber.undeclare()
    args.out.write_bytes(msgpack.packb({"raw": raw, "wall_to_mono": wall_to_mono}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
