"""``roger bench worker``: what a learner worker spends per robot and tick.

One worker's work, in this process (no daemon, no pipes): ``--robots`` models served in turn,
as a worker process of the daemon serves the robots assigned to it (4 is what each of the two
default workers serves for 8 robots on 2 cores; docs/fleet.md, *A pool of workers*). Each
robot is fed its own slice of a shipped stream (``--stream aibo``, the default, or
``synthetic``), cycled. Each tick, for each robot, the worker's own request handler
(:class:`roger_daemon.daemon.worker._Worker`) gets what the daemon sends it: a ``learn``
request with the pair, then, as the worker does when no request waits, the experts' labels
counted ahead (``idle``), then a ``predict`` request for the next perception; requests and
replies go through msgpack as over the pipe. ``--rate`` paces the ticks (default 30 Hz:
between ticks the process sleeps and its caches go cold, as in the daemon; 0: back to back).
Every robot first learns ``--warmup`` pairs, then ``--duration`` seconds are measured.

Reported: the process's CPU time per robot-tick (everything above, for one robot), and the
wall-time p50/p99 of the learn, labels and predict parts; the machine record. BLAS and the
learner's kernels run on one thread, as in a worker of a daemon with more robots than cores,
and large allocations are mapped as in a worker (``roger_daemon.daemon.memory``).
"""

from __future__ import annotations

import argparse
import json
import time
from typing import Any

import msgpack
import numpy as np

from protocols.packing import packb
from roger_daemon.bench.streams import FLEET_STREAMS, FeedStream, feed_stream
from roger_daemon.console import require
from roger_daemon.machine import describe, finish, machine_record

__all__ = ["configure", "run", "serve_ticks"]

PARTS = ("learn", "labels", "predict")


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roger bench worker``."""
    parser.add_argument("--robots", type=int, default=1,
                        help="models the worker serves in turn (default 1)")
    parser.add_argument("--rate", type=float, default=30.0,
                        help="ticks per second (default 30; 0: back to back)")
    parser.add_argument("--duration", "--seconds", dest="seconds", type=float, default=20.0,
                        metavar="S", help="measured seconds (default 20; --seconds: the "
                                          "deprecated spelling)")
    parser.add_argument("--warmup", type=int, default=400,
                        help="pairs each robot learns before the measurement (default 400)")
    parser.add_argument("--stream", choices=FLEET_STREAMS, default="aibo",
                        help="aibo: the recorded AIBO demonstrations (default); synthetic")
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def _through_pipe(msg: dict[str, Any]) -> dict[str, Any]:
    """``msg`` as the worker receives it: packed and unpacked as on the pipe."""
    out: dict[str, Any] = msgpack.unpackb(packb(msg), raw=False)
    return out


def _workers(robots: int, stream: FeedStream) -> list[Any]:
    """One loaded worker handler per robot (the default configuration's model, seed ``r``)."""
    from roger_daemon.config import parse_config
    from roger_daemon.daemon.worker import _Worker

    cfg = parse_config({"robots": [{"id": f"r{r}", "seed": r} for r in range(robots)]})
    out = []
    for robot in cfg.robots:
        w = _Worker()
        w.handle(_through_pipe({
            "op": "load", "robot": robot.id, "x_dim": stream.x.shape[1],
            "y_dim": stream.y.shape[1], "model": robot.model, "seed": robot.seed,
            "params": robot.params.to_mapping(), "state": None, "codes": None}))
        out.append(w)
    return out


def serve_ticks(workers: list[Any], stream: FeedStream, ticks: range,
                times: dict[str, list[float]] | None = None) -> None:
    """Serve ``ticks`` to every worker handler: learn, labels, predict per robot and tick;
    with ``times``, append each part's wall time (s) to ``times[part]``."""
    n = len(stream.x)
    vocab = sorted(set(stream.labels))
    code = {label: i for i, label in enumerate(vocab)}
    for tick in ticks:
        for r, w in enumerate(workers):
            j = (r * n // len(workers) + tick) % n
            learn = _through_pipe({
                "op": "learn", "x": stream.x[j].astype("<f8").tobytes(),
                "y": stream.y[j].astype("<f8").tobytes(), "code": code[stream.labels[j]],
                "tick": tick, **({"vocab": vocab} if tick == 0 else {})})
            predict = _through_pipe({"op": "predict", "tick": tick + 1, "t": (tick + 1) / 30,
                                     "x": stream.x[(j + 1) % n].astype("<f8").tobytes()})
            t0 = time.perf_counter()
            reply = w.handle(learn)
            t1 = time.perf_counter()
            w.idle()
            t2 = time.perf_counter()
            answer = w.handle(predict)
            t3 = time.perf_counter()
            if not (reply.get("ok") and answer.get("ok")):
                raise RuntimeError(f"r{r} tick {tick}: the worker failed ({reply}, {answer})")
            _through_pipe(reply)
            _through_pipe(answer)
            if times is not None:
                for part, dt in zip(PARTS, (t1 - t0, t2 - t1, t3 - t2), strict=True):
                    times[part].append(dt)


def _measure(args: argparse.Namespace) -> dict[str, Any]:
    from roger_daemon.blas import pin_blas_threads
    from roger_daemon.daemon.memory import limit_heap_growth
    from roger_daemon.learner.engine.jit import set_threads

    pin_blas_threads(1)
    set_threads(1)
    limit_heap_growth()  # a worker process's allocator rule (roger_daemon.daemon.worker.main)
    stream = feed_stream(args.stream)
    workers = _workers(args.robots, stream)
    serve_ticks(workers, stream, range(args.warmup))
    times: dict[str, list[float]] = {part: [] for part in PARTS}
    tick = args.warmup
    cpu0, start = time.process_time(), time.monotonic()
    due = start
    while time.monotonic() - start < args.seconds:
        serve_ticks(workers, stream, range(tick, tick + 1), times)
        tick += 1
        if args.rate > 0:
            due += 1.0 / args.rate
            time.sleep(max(0.0, due - time.monotonic()))
    cpu, wall = time.process_time() - cpu0, time.monotonic() - start
    served = (tick - args.warmup) * args.robots
    out: dict[str, Any] = {
        "robot_ticks": served, "wall_s": round(wall, 2),
        "cpu_ms_per_robot_tick": round(1e3 * cpu / max(served, 1), 3),
        "experts": [int(w.rt.model.n_experts) for w in workers],
    }
    for part, values in times.items():
        v = np.asarray(values) * 1e3
        out[f"{part}_p50_ms"] = round(float(np.percentile(v, 50)), 3)
        out[f"{part}_p99_ms"] = round(float(np.percentile(v, 99)), 3)
    return out


def run(args: argparse.Namespace) -> int:
    """Run the benchmark; print a table or one JSON object."""
    require(args.robots >= 1, "--robots", "an integer >= 1", args.robots)
    require(args.rate >= 0, "--rate", "a number >= 0 (0: back to back)", args.rate)
    require(args.seconds > 0, "--duration", "a number > 0", args.seconds)
    require(args.warmup >= 0, "--warmup", "an integer >= 0", args.warmup)
    machine = machine_record()
    if not args.json:
        print(f"roger bench worker: {args.robots} model(s) in one worker, "
              f"{args.rate:g} Hz, {args.seconds:g} s after {args.warmup} pairs each "
              f"({describe(machine)})")
    result = {**_measure(args),
              "settings": {"robots": args.robots, "rate_hz": args.rate,
                           "seconds": args.seconds, "warmup": args.warmup,
                           "stream": args.stream},
              "machine": finish(machine)}
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    print(f"CPU per robot-tick {result['cpu_ms_per_robot_tick']:.2f} ms "
          f"({result['robot_ticks']} robot-ticks in {result['wall_s']:.1f} s)")
    for part in PARTS:
        print(f"  {part:8s} p50 {result[part + '_p50_ms']:.3f} ms  "
              f"p99 {result[part + '_p99_ms']:.3f} ms")
    print(f"  experts per robot: {result['experts']}")
    return 0
