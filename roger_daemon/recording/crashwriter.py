"""A recorder process to be killed: ``python -m roger_daemon.recording.crashwriter --out DIR``.

It records a daemon-like message mix (perception, action, prediction with a multimap, command)
at ``--rate`` ticks per second in real time, calling ``poll`` every tick, and prints one line
``flushed <tick> <wall_ns>`` on stdout after every flush that reached the OS: everything up to
that tick is then in the file, whatever happens to the process. Used by the SIGKILL test and by
``roger bench recorder``.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from protocols import keys
from protocols.messages import Action, Command, ExpertOutput, Perception, Prediction, encode
from roger_daemon.recording.metadata import session_metadata
from roger_daemon.recording.writer import SessionRecorder

__all__ = ["main", "tick_payloads"]


def tick_payloads(robot: str, tick: int, n_experts: int = 4) -> list[tuple[str, bytes]]:
    """The four messages of one tick, AIBO-sized (23-D perception, 9-D actions)."""
    rng = np.random.default_rng(tick)
    x, y = rng.normal(size=23), rng.normal(size=9)
    t = tick / 30
    mm = tuple(
        ExpertOutput(expert=e, p=1 / n_experts, mean=y + e, var=np.full(9, 0.1 + e), n=10 * e,
                     label="seek")
        for e in range(n_experts)
    )
    return [
        (keys.perception(robot), encode(Perception(robot, tick, t, x=x))),
        (keys.action(robot), encode(Action(robot, tick, t, y=y, label="seek"))),
        (keys.prediction(robot), encode(Prediction(robot, tick, t, mean=y, var=np.full(9, 0.1),
                                                   expert=0, multimap=mm, updates=tick))),
        (keys.command(robot), encode(Command(robot, tick, t, y=y, source="hcc"))),
    ]


def main(argv: list[str] | None = None) -> int:
    """Record until killed (or ``--ticks``, then wait to be killed)."""
    ap = argparse.ArgumentParser(prog="crashwriter")
    ap.add_argument("--out", required=True)
    ap.add_argument("--rate", type=float, default=30.0)
    ap.add_argument("--flush-interval", type=float, default=1.0)
    ap.add_argument("--ticks", type=int, default=0, help="stop writing after this many (0: never)")
    ap.add_argument("--compression", default="zstd")
    args = ap.parse_args(argv)
    robot = "crash"
    rec = SessionRecorder(args.out, robot=robot, metadata=session_metadata(robot=robot),
                          flush_interval_s=args.flush_interval, compression=args.compression)
    print(f"file {rec.path}", flush=True)
    period = 1.0 / args.rate if args.rate > 0 else 0.0
    t_next = time.monotonic()
    tick = 0
    flushes = 0
    while args.ticks == 0 or tick < args.ticks:
        now = time.time_ns()
        for key, payload in tick_payloads(robot, tick):
            rec.write(key, payload, log_time_ns=now, publish_time_ns=now, sequence=tick)
        rec.poll(time.monotonic_ns())
        if rec.stats.flushes != flushes:
            flushes = rec.stats.flushes
            print(f"flushed {tick} {time.time_ns()}", flush=True)
        tick += 1
        if period:
            t_next += period
            delay = t_next - time.monotonic()
            if delay > 0:
                time.sleep(delay)
    rec.flush()
    print(f"flushed {tick - 1} {time.time_ns()}", flush=True)
    print("done", flush=True)
    while True:  # wait for the kill with the file still open (no footer)
        time.sleep(1)


if __name__ == "__main__":
    sys.exit(main())
