"""``roger bench recorder``: cost of recording in a 30 Hz loop, and what a SIGKILL loses.

* **write+poll**: per tick, the four messages of a daemon tick (perception, action, prediction
  with a 4-expert multimap, command; ~1.6 kB) written, then ``poll``; on a fake 30 Hz clock so
  the flush falls every 30 ticks. Reports per-tick cost percentiles, the flush ticks separately,
  and ``close``.
* **sigkill**: a real writer process (``crashwriter``) recording in real time is killed with
  SIGKILL at a random moment; the file is salvaged and the loss measured as kill time minus the
  log time of the last message kept (bounded by the flush interval plus one tick).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from roger_daemon.recording.crashwriter import tick_payloads
from roger_daemon.recording.mcapio import LogReader
from roger_daemon.recording.metadata import session_metadata
from roger_daemon.recording.writer import SessionRecorder

__all__ = ["bench_sigkill", "bench_write_poll", "configure", "run"]


def _pct(a: list[float]) -> dict[str, float]:
    v = np.asarray(a) * 1e6
    if v.size == 0:
        return {"n": 0}
    return {
        "n": int(v.size),
        "p50_us": round(float(np.percentile(v, 50)), 1),
        "p99_us": round(float(np.percentile(v, 99)), 1),
        "max_us": round(float(v.max()), 1),
    }


def bench_write_poll(ticks: int = 3000, compression: str = "zstd",
                     directory: str | None = None) -> dict[str, Any]:
    """Per-tick cost of write (4 messages) + poll on a fake 30 Hz clock."""
    payloads = [tick_payloads("bench", t) for t in range(64)]
    with tempfile.TemporaryDirectory(dir=directory) as d:
        rec = SessionRecorder(d, robot="bench", metadata=session_metadata(robot="bench"),
                              compression=compression)
        plain: list[float] = []
        flush: list[float] = []
        writes: list[float] = []
        t0 = 1_000_000_000
        for t in range(ticks):
            now = t0 + t * 33_333_333
            before = rec.stats.flushes
            a = time.perf_counter()
            for key, p in payloads[t % 64]:
                rec.write(key, p, log_time_ns=now, publish_time_ns=now, sequence=t)
            b = time.perf_counter()
            rec.poll(now)
            c = time.perf_counter()
            writes.append(b - a)
            (flush if rec.stats.flushes != before else plain).append(c - a)
        a = time.perf_counter()
        rec.close()
        close_s = time.perf_counter() - a
        size = rec.stats.bytes
    raw = sum(len(p) for t in range(ticks) for _, p in payloads[t % 64])
    return {
        "compression": compression,
        "ticks": ticks,
        "messages": ticks * 4,
        "payload_bytes": raw,
        "file_bytes": size,
        "write_4_msgs": _pct(writes),
        "tick_write_poll_no_flush": _pct(plain),
        "tick_write_poll_with_flush": _pct(flush),
        "close_ms": round(close_s * 1e3, 2),
    }


def bench_sigkill(trials: int = 5, rate: float = 30.0, flush_interval: float = 1.0,
                  seed: int = 0, directory: str | None = None) -> dict[str, Any]:
    """Kill a real recorder with SIGKILL at random times; measure what the log lost."""
    rnd = random.Random(seed)
    losses: list[float] = []
    lost_ticks: list[int] = []
    for _ in range(trials):
        with tempfile.TemporaryDirectory(dir=directory) as d:
            proc = subprocess.Popen(
                [sys.executable, "-m", "roger_daemon.recording.crashwriter", "--out", d,
                 "--rate", str(rate), "--flush-interval", str(flush_interval)],
                stdout=subprocess.PIPE, text=True,
            )
            assert proc.stdout is not None
            proc.stdout.readline()  # "file ..."
            proc.stdout.readline()  # first flush: the writer is running
            time.sleep(rnd.uniform(1.0, 3.0))
            t_kill = time.time_ns()
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait()
            proc.stdout.close()
            path = next(Path(d).glob("*.mcap"))
            reader = LogReader(path)
            last_t, last_tick = 0, -1
            for lm in reader.messages():
                last_t = max(last_t, lm.message.log_time)
                last_tick = max(last_tick, lm.message.sequence)
            losses.append((t_kill - last_t) / 1e9)
            lost_ticks.append(round((t_kill - last_t) / 1e9 * rate))
    return {
        "trials": trials,
        "rate_hz": rate,
        "flush_interval_s": flush_interval,
        "lost_s_max": round(max(losses), 3),
        "lost_s_mean": round(float(np.mean(losses)), 3),
        "lost_ticks_max": max(lost_ticks),
        "lost_s_each": [round(v, 3) for v in losses],
    }


def configure(parser: argparse.ArgumentParser) -> None:
    """Options of ``roger bench recorder``."""
    parser.add_argument("--ticks", type=int, default=3000,
                        help="ticks of synthetic traffic to record (default 3000)")
    parser.add_argument("--trials", type=int, default=5, help="SIGKILL trials (0: skip)")
    parser.add_argument("--dir", default=None, help="where temporary files go (default /tmp)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def run(args: argparse.Namespace) -> int:
    """Run both benchmarks and print a table or JSON."""
    out: dict[str, Any] = {
        "write_poll": [bench_write_poll(args.ticks, c, args.dir) for c in ("zstd", "lz4")],
    }
    if args.trials:
        out["sigkill"] = bench_sigkill(args.trials, directory=args.dir)
    if args.json:
        print(json.dumps(out, indent=2))
        return 0
    for r in out["write_poll"]:
        print(f"[{r['compression']}] {r['messages']} msgs, {r['payload_bytes']} B payload -> "
              f"{r['file_bytes']} B file; close {r['close_ms']} ms")
        for k in ("write_4_msgs", "tick_write_poll_no_flush", "tick_write_poll_with_flush"):
            print(f"  {k:28s} {r[k]}")
    if "sigkill" in out:
        s = out["sigkill"]
        print(f"SIGKILL x{s['trials']} at {s['rate_hz']} Hz, flush every "
              f"{s['flush_interval_s']} s: lost max {s['lost_s_max']} s "
              f"(mean {s['lost_s_mean']} s, max {s['lost_ticks_max']} ticks)")
    return 0
