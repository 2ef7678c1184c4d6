"""``roger bench daemon``: the daemon end to end over loopback, learning while it serves.

The daemon runs as a subprocess (``python -m roger_daemon daemon``) on a free loopback port;
this process is the robot and the demonstrator, feeding the shipped synthetic stream
(:func:`roger_daemon.learner.synthetic.subtask_stream`, 23-D perception, 9-D actions with
subtask labels). Three phases, each with a fresh daemon and model:

1. **lockstep** (``--duration``): at ``--rate`` Hz the client publishes perception(t), waits
   for prediction(t), then publishes action(t). ``latency_*`` is perception published ->
   prediction received, measured in this process (same clock at both ends). It includes the
   time a perception waits while the loop finishes a ``learn_one`` (reported as
   ``learn_ms_*``); then a few seconds in mode ``predict`` give the latency without learning
   (``predict_only_latency_*``: transport and daemon overhead only).
2. **realtime** (``--duration``): the client publishes perception/action pairs at ``--rate``
   Hz; the daemon publishes on its own 30 Hz timer. ``period_jitter_p99_ms`` is the daemon's
   own measurement of its publisher (|actual period - 1/rate|, from its status);
   ``client_period_jitter_p99_ms`` is the same seen at the receiver (adds transport noise).
   ``updates_per_s`` is the learning rate sustained meanwhile (it cannot exceed the feed rate).
3. **saturate** (``--saturate-duration``, 0 to skip): pairs are fed at ``--saturate-rate`` Hz
   in realtime mode; ``updates_per_s_max`` is what the daemon learns per second while still
   publishing at 30 Hz (the queue overflows and drops are counted, as they should be).

Warm-up: the first second of each phase is not measured. Numbers depend on the machine and on
what else runs on it; the machine record (:mod:`roger_daemon.machine`: load average at start
and end, speed probe) is reported alongside.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from protocols.aibo import SUBTASKS
from roger_daemon.harness import Client, DaemonProcess, free_port, write_config
from roger_daemon.learner.synthetic import subtask_stream
from roger_daemon.machine import describe, finish, machine_record

__all__ = ["configure", "run"]

TARGETS = {"latency_p99_ms": 10.0, "period_jitter_p99_ms": 5.0}


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roger bench daemon``."""
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--duration", "--seconds", dest="seconds", type=float, default=10.0,
                        metavar="S", help="measured seconds of the lockstep and realtime phases "
                                          "(default 10; --seconds: the deprecated spelling)")
    parser.add_argument("--rate", type=float, default=30.0, help="feed and prediction rate (Hz)")
    parser.add_argument("--saturate-duration", "--saturate-seconds", dest="saturate_seconds",
                        type=float, default=5.0, metavar="S",
                        help="length of the saturation phase in seconds (0 skips it; default "
                             "5; --saturate-seconds: the deprecated spelling)")
    parser.add_argument("--saturate-rate", type=float, default=300.0,
                        help="feed rate of the saturation phase (Hz, default 300)")
    parser.add_argument("--recording", action="store_true",
                        help="let the daemon record MCAP as it does by default in production")
    parser.add_argument("--no-wal", action="store_true",
                        help="switch the write-ahead log off (checkpoint.wal = false), to "
                             "measure what durable acknowledgements cost")
    parser.add_argument("--workers", choices=("process", "inline"), default=None,
                        help="where the daemon learns: a worker process per robot or its own "
                             "loop (daemon.workers; default: the daemon's default)")
    parser.add_argument("--keep", type=Path, default=None,
                        help="keep the daemon's logs, checkpoints and recordings here")


def _pct(values: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(values), q)) if values else float("nan")


class _Phase:
    def __init__(self, workdir: Path, name: str, clock: str, rate: float,
                 recording: bool, *, wal: bool = True, workers: str | None = None) -> None:
        self.port = free_port()
        daemon: dict[str, Any] = {"clock": clock, "rate_hz": rate, "queue_size": 256}
        if workers is not None:
            daemon["workers"] = workers
        cfg = write_config(
            workdir / f"{name}.toml", port=self.port, workdir=workdir / name,
            daemon=daemon,
            recording={"enabled": recording},
            checkpoint={"wal": wal},
        )
        self.daemon = DaemonProcess(cfg, args=["--fresh"])
        self.daemon.wait_ready()
        self.client = Client(f"tcp/127.0.0.1:{self.port}")
        self.client.wait_daemon()

    def close(self) -> int:
        self.client.close()
        code, _ = self.daemon.terminate()
        return code


def _lockstep(workdir: Path, args: argparse.Namespace, stream: Any) -> dict[str, Any]:
    ph = _Phase(workdir, "lockstep", "lockstep", args.rate, args.recording,
                wal=not args.no_wal, workers=args.workers)
    c = ph.client
    period = 1.0 / args.rate
    lat: list[float] = []
    lost = 0
    t0 = time.monotonic()
    tick = 0
    try:
        while time.monotonic() - t0 < args.seconds + 1.0:
            i = tick % len(stream.x)
            sent = c.perception(tick, stream.x[i])
            try:
                got = c.wait_received(tick, timeout=1.0)
                if time.monotonic() - t0 >= 1.0:
                    lat.append((got.recv_ns - sent) / 1e6)
            except TimeoutError:
                lost += 1
            c.action(tick, stream.y[i], SUBTASKS[int(stream.labels[i]) % len(SUBTASKS)])
            tick += 1
            time.sleep(max(0.0, t0 + tick * period - time.monotonic()))
        st = c.wait_status(lambda s: s.ticks >= tick)
        # Reference: the same loop with learning switched off (mode "predict"), to separate
        # the transport + daemon overhead from the time a perception waits for learn_one.
        c.control("mode", "predict")
        c.wait_status(lambda s: s.mode == "predict")
        lat_predict: list[float] = []
        t1 = time.monotonic()
        while time.monotonic() - t1 < min(args.seconds, 5.0):
            i = tick % len(stream.x)
            sent = c.perception(tick, stream.x[i])
            try:
                got = c.wait_received(tick, timeout=1.0)
                lat_predict.append((got.recv_ns - sent) / 1e6)
            except TimeoutError:
                lost += 1
            tick += 1
            time.sleep(max(0.0, t1 + (len(lat_predict) + 1) * period - time.monotonic()))
    finally:
        code = ph.close()
    return {
        "latency_p50_ms": _pct(lat, 50), "latency_p99_ms": _pct(lat, 99),
        "predict_only_latency_p50_ms": _pct(lat_predict, 50),
        "predict_only_latency_p99_ms": _pct(lat_predict, 99),
        "latency_max_ms": max(lat) if lat else float("nan"), "predictions": len(lat),
        "lost_predictions": lost, "updates": st.updates, "experts": st.experts,
        "daemon_latency_p99_ms": st.latency_ms_p99, "learn_ms_p50": st.info["learn_ms_p50"],
        "learn_ms_p99": st.info["learn_ms_p99"], "dropped": st.dropped, "exit_code": code,
        "wal_commits": st.info.get("wal_commits", 0),
        "wal_commit_ms_p50": st.info.get("wal_commit_ms_p50", 0.0),
        "wal_commit_ms_p99": st.info.get("wal_commit_ms_p99", 0.0),
        "wal_commit_ms_max": st.info.get("wal_commit_ms_max", 0.0),
    }


def _feed(c: Client, stream: Any, rate: float, seconds: float) -> tuple[int, int, int]:
    """Feed pairs at ``rate`` for ``seconds``; return (first tick measured, ticks, t_begin_ns)."""
    period = 1.0 / rate
    t0 = time.monotonic()
    tick = 0
    first = -1
    while time.monotonic() - t0 < seconds + 1.0:
        if first < 0 and time.monotonic() - t0 >= 1.0:
            first = tick
        i = tick % len(stream.x)
        c.perception(tick, stream.x[i])
        c.action(tick, stream.y[i], SUBTASKS[int(stream.labels[i]) % len(SUBTASKS)])
        tick += 1
        time.sleep(max(0.0, t0 + tick * period - time.monotonic()))
    return first, tick, int((t0 + 1.0) * 1e9)


def _realtime(workdir: Path, args: argparse.Namespace, stream: Any) -> dict[str, Any]:
    ph = _Phase(workdir, "realtime", "realtime", args.rate, args.recording,
                wal=not args.no_wal, workers=args.workers)
    c = ph.client
    try:
        c.wait_status()
        start = c.wait_status()
        _, _, w0 = _feed(c, stream, args.rate, args.seconds)
        end = c.wait_status()
    finally:
        code = ph.close()
    recv = [r.recv_ns for r in c.predictions if r.recv_ns >= w0]
    periods = np.diff(np.asarray(recv, dtype=np.int64)) / 1e6
    nominal = 1000.0 / args.rate
    dt = (end.uptime_s - start.uptime_s) or float("nan")
    return {
        "period_jitter_p99_ms": end.info["period_jitter_ms_p99"],
        "period_jitter_p50_ms": end.info["period_jitter_ms_p50"],
        "tick_lateness_p99_ms": end.info["tick_lateness_ms_p99"],
        "missed_ticks": end.info["missed_ticks"],
        "client_period_jitter_p99_ms": _pct(list(np.abs(periods - nominal)), 99),
        "rate_hz_measured": (len(recv) - 1) / ((recv[-1] - recv[0]) / 1e9) if len(recv) > 1
        else float("nan"),
        "updates_per_s": (end.updates - start.updates) / dt,
        "updates": end.updates, "experts": end.experts, "dropped": end.dropped,
        "learn_ms_p50": end.info["learn_ms_p50"], "learn_ms_p99": end.info["learn_ms_p99"],
        "exit_code": code,
    }


def _saturate(workdir: Path, args: argparse.Namespace, stream: Any) -> dict[str, Any]:
    ph = _Phase(workdir, "saturate", "realtime", args.rate, args.recording,
                wal=not args.no_wal, workers=args.workers)
    c = ph.client
    try:
        start = c.wait_status()
        _feed(c, stream, args.saturate_rate, args.saturate_seconds)
        end = c.wait_status()
    finally:
        code = ph.close()
    dt = end.uptime_s - start.uptime_s
    return {
        "updates_per_s_max": (end.updates - start.updates) / dt if dt > 0 else float("nan"),
        "updates": end.updates, "dropped": end.dropped, "experts": end.experts,
        "period_jitter_p99_ms": end.info["period_jitter_ms_p99"],
        "missed_ticks": end.info["missed_ticks"], "exit_code": code,
    }


def _phase(name: str, fn: Any, workdir: Path, args: argparse.Namespace,
           stream: Any) -> dict[str, Any]:
    """Run one phase; if it fails, say so with the end of that daemon's log."""
    try:
        result: dict[str, Any] = fn(workdir, args, stream)
    except Exception as exc:
        log = workdir / f"{name}.log"
        tail = log.read_text(errors="replace")[-3000:] if log.exists() else "(no log)"
        raise RuntimeError(f"{name} phase failed: {exc}\n--- daemon log (end) ---\n{tail}") \
            from exc
    if result.get("exit_code") not in (0, None):
        tail = (workdir / f"{name}.log").read_text(errors="replace")[-3000:]
        raise RuntimeError(f"{name} phase: the daemon exited with {result['exit_code']}\n"
                           f"--- daemon log (end) ---\n{tail}")
    return result


def run(args: argparse.Namespace) -> int:
    """Run the phases and print a table or one JSON object."""
    stream = subtask_stream(4000)
    machine = machine_record()
    with tempfile.TemporaryDirectory(prefix="roger-bench-daemon-") as tmp:
        workdir = args.keep or Path(tmp)
        workdir.mkdir(parents=True, exist_ok=True)
        lock = _phase("lockstep", _lockstep, workdir, args, stream)
        real = _phase("realtime", _realtime, workdir, args, stream)
        sat = _phase("saturate", _saturate, workdir, args, stream) if (
            args.saturate_seconds > 0) else {}
    result: dict[str, Any] = {
        "latency_p50_ms": lock["latency_p50_ms"],
        "latency_p99_ms": lock["latency_p99_ms"],
        "period_jitter_p99_ms": real["period_jitter_p99_ms"],
        "updates_per_s": real["updates_per_s"],
        "updates_per_s_max": sat.get("updates_per_s_max", float("nan")),
        "targets": TARGETS,
        "meets_targets": bool(lock["latency_p99_ms"] <= TARGETS["latency_p99_ms"]
                              and real["period_jitter_p99_ms"]
                              <= TARGETS["period_jitter_p99_ms"]),
        "phases": {"lockstep": lock, "realtime": real, "saturate": sat},
        "settings": {"seconds": args.seconds, "rate_hz": args.rate,
                     "saturate_seconds": args.saturate_seconds,
                     "saturate_rate_hz": args.saturate_rate, "recording": args.recording,
                     "wal": not args.no_wal, "workers": args.workers or "default"},
        "machine": finish(machine),
    }
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    rows = [
        ("latency p50 (perception -> prediction, lockstep)", lock["latency_p50_ms"], "ms"),
        ("latency p99", lock["latency_p99_ms"], f"ms (target <= {TARGETS['latency_p99_ms']})"),
        ("learn_one p50 / p99 in the daemon (lockstep)", lock["learn_ms_p50"], "ms"),
        ("", lock["learn_ms_p99"], "ms"),
        ("latency p99 with learning off (mode predict)", lock["predict_only_latency_p99_ms"],
         "ms"),
        ("write-ahead log commit p50 / p99 (lockstep)", lock["wal_commit_ms_p50"], "ms"),
        ("", lock["wal_commit_ms_p99"], "ms" + ("" if not args.no_wal else " (--no-wal)")),
        ("30 Hz publisher period jitter p99 (daemon)", real["period_jitter_p99_ms"],
         f"ms (target <= {TARGETS['period_jitter_p99_ms']})"),
        ("period jitter p99 seen by the client", real["client_period_jitter_p99_ms"], "ms"),
        ("prediction rate measured", real["rate_hz_measured"], "Hz"),
        ("updates/s sustained at the feed rate", real["updates_per_s"], "1/s"),
        ("updates/s when saturated", result["updates_per_s_max"], "1/s"),
    ]
    print(f"roger bench daemon  ({describe(machine)})")
    for name, value, unit in rows:
        print(f"  {name:<50} {value:10.3f} {unit}")
    print(f"  model at the end: lockstep {lock['updates']} updates/{lock['experts']} experts, "
          f"realtime {real['updates']}/{real['experts']}, dropped "
          f"{real['dropped']} (realtime) {sat.get('dropped', 0)} (saturate)")
    return 0
