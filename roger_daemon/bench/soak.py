"""``roger bench soak``: the daemon's memory over a long run, learning at 30 Hz.

A real daemon subprocess (realtime clock, write-ahead log, recording and periodic
checkpoints as configured by default) serves ``--robots`` robots; this process feeds each
with perception/action pairs at ``--rate`` Hz (``--stream aibo``, the default: the recorded AIBO
demonstrations, cycled, the realistic workload of the default configuration; ``synthetic``: a
20,000-point synthetic stream, cycled, which keeps opening experts), and
every ``--interval`` seconds samples the resident set size (``VmRSS`` in ``/proc``) of the
daemon's process and of its children (the learner workers), with the model size from status.

Reported: the samples; the growth of the total RSS from the end of the warm-up
(``--warmup-duration``, default 600 s, or a third of a shorter run) to the end, in % (target
< 5 %); the same for the loop process and the workers; and the newest checkpoint of each
robot: its size, its distinct experts (every particle's, shared ones counted once), bytes per
expert, and which arrays take the bytes (the per-point history grows with the data learned,
not with the experts).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from roger_daemon.bench.fleet_client import FleetClient, child_pids, feed
from roger_daemon.bench.streams import FLEET_STREAMS, feed_stream
from roger_daemon.console import require
from roger_daemon.daemon.checkpoint import list_checkpoints, read_checkpoint
from roger_daemon.harness import DaemonProcess, free_port, write_config
from roger_daemon.machine import describe, finish, machine_record

__all__ = ["checkpoint_profile", "configure", "rss_mb", "run"]

TARGET_GROWTH_PCT = 5.0


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roger bench soak``."""
    parser.add_argument("--duration", type=float, default=None, metavar="S",
                        help="length in seconds (default 3600)")
    parser.add_argument("--minutes", type=float, default=None, metavar="MIN",
                        help="deprecated: the length in minutes (use --duration S)")
    parser.add_argument("--warmup-duration", dest="warmup_s", type=float, default=None,
                        metavar="S", help="growth is measured from here, in seconds (default "
                                          "600, or a third of the run if shorter than 30 min)")
    parser.add_argument("--warmup-minutes", type=float, default=None, metavar="MIN",
                        help="deprecated: the same in minutes (use --warmup-duration S)")
    parser.add_argument("--robots", type=int, default=1, help="robots fed (default 1)")
    parser.add_argument("--stream", choices=FLEET_STREAMS, default="aibo",
                        help="aibo: the recorded AIBO demonstrations, cycled (default); "
                             "synthetic: a 20,000-point synthetic stream")
    parser.add_argument("--rate", type=float, default=30.0, help="feed rate per robot (Hz)")
    parser.add_argument("--interval", type=float, default=10.0,
                        help="seconds between RSS samples (default 10)")
    parser.add_argument("--set", dest="overrides", action="append", default=[],
                        metavar="SECTION.KEY=VALUE", help="daemon config override")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--keep", type=Path, default=None,
                        help="keep the daemon's files here")


def rss_mb(pid: int) -> float:
    """Resident set size of ``pid`` in MB (0 if it is gone)."""
    try:
        with open(f"/proc/{pid}/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return 0.0


def checkpoint_profile(directory: Path, robot: str) -> dict[str, Any]:
    """Size of the newest checkpoint of ``robot`` per distinct expert, and its largest arrays."""
    paths = list_checkpoints(directory, robot)
    if not paths:
        return {}
    ck = read_checkpoint(paths[0])
    size = paths[0].stat().st_size
    experts = int(len(ck.model.get("expert_id", ())))
    by_array = sorted(((k, int(v.nbytes)) for k, v in ck.model.items()),
                      key=lambda kv: -kv[1])
    history = sum(n for k, n in by_array if k.startswith("history_"))
    return {
        "path": str(paths[0]), "bytes": size, "updates": ck.meta.updates,
        "distinct_experts": experts,
        "bytes_per_expert": (size - history) / experts if experts else float("nan"),
        "history_bytes": history,
        "largest_arrays": dict(by_array[:6]),
    }


def _growth(samples: list[dict[str, Any]], key: str, t0: float) -> float:
    after = [s for s in samples if s["t_s"] >= t0]
    if len(after) < 2 or after[0][key] <= 0:
        return float("nan")
    return 100.0 * float(after[-1][key] - after[0][key]) / float(after[0][key])


def _sample(daemon: DaemonProcess, fleet: FleetClient, t0: float) -> dict[str, Any]:
    pid = daemon.proc.pid
    main = rss_mb(pid)
    workers = sum(rss_mb(c) for c in child_pids(pid))
    st = {r: fleet.status[r][-1][1] for r in fleet.robots if fleet.status[r]}
    return {"t_s": round(time.monotonic() - t0, 1), "rss_main_mb": round(main, 1),
            "rss_workers_mb": round(workers, 1), "rss_total_mb": round(main + workers, 1),
            "updates": sum(s.updates for s in st.values()),
            "experts": sum(s.experts for s in st.values()),
            "dropped": sum(s.dropped for s in st.values()),
            "loadavg_1m": round(os.getloadavg()[0], 2)}


def _soak(workdir: Path, args: argparse.Namespace) -> dict[str, Any]:
    robots = [f"r{i}" for i in range(args.robots)]
    port = free_port()
    cfg = write_config(workdir / "soak.toml", port=port, workdir=workdir,
                       daemon={"clock": "realtime", "rate_hz": args.rate},
                       checkpoint={"every_updates": 1000, "every_s": 60.0},
                       recording={"enabled": True},
                       robots=[{"id": r, "seed": i} for i, r in enumerate(robots)])
    daemon = DaemonProcess(cfg, args=["--fresh", *(a for o in args.overrides
                                                   for a in ("--set", o))])
    samples: list[dict[str, Any]] = []
    fleet = None
    try:
        daemon.wait_ready(120.0)
        fleet = FleetClient(f"tcp/127.0.0.1:{port}", robots)
        time.sleep(1.0)
        t0 = time.monotonic()
        end = t0 + args.minutes * 60.0
        stream = feed_stream(args.stream, 20000)
        feeder = threading.Thread(target=feed, args=(fleet, stream, args, False, end),
                                  daemon=True)
        feeder.start()
        while time.monotonic() < end:
            samples.append(_sample(daemon, fleet, t0))
            s = samples[-1]  # progress: on stdout, or on stderr under --json
            print(f"  {s['t_s']:8.0f} s  RSS {s['rss_total_mb']:7.1f} MB (loop "
                  f"{s['rss_main_mb']:.1f}, workers {s['rss_workers_mb']:.1f})  updates "
                  f"{s['updates']}  experts {s['experts']}  load {s['loadavg_1m']}",
                  flush=True, file=sys.stderr if args.json else sys.stdout)
            time.sleep(max(0.0, min(args.interval, end - time.monotonic())))
        feeder.join()
        samples.append(_sample(daemon, fleet, t0))
    finally:
        if fleet is not None:
            fleet.close()
        code = daemon.terminate(60.0)[0] if daemon.proc.poll() is None else daemon.proc.poll()
    return {"samples": samples, "exit_code": code,
            "checkpoints": {r: checkpoint_profile(workdir / "checkpoints", r) for r in robots}}


def run(args: argparse.Namespace) -> int:
    """Run the soak; print a table or one JSON object."""
    if args.minutes is not None:  # the deprecated spelling, in minutes
        require(args.duration is None, "--minutes", "not given with --duration", args.minutes)
        require(args.minutes > 0, "--minutes", "a number > 0", args.minutes)
        args.duration = args.minutes * 60.0
    args.duration = 3600.0 if args.duration is None else args.duration
    require(args.duration > 0, "--duration", "a number > 0", args.duration)
    args.minutes = args.duration / 60.0
    require(args.robots >= 1, "--robots", "an integer >= 1", args.robots)
    require(args.interval > 0, "--interval", "a number > 0", args.interval)
    if args.warmup_minutes is not None:  # the deprecated spelling, in minutes
        require(args.warmup_s is None, "--warmup-minutes", "not given with --warmup-duration",
                args.warmup_minutes)
        args.warmup_s = args.warmup_minutes * 60.0
    require(args.warmup_s is None or args.warmup_s >= 0, "--warmup-duration", "a number >= 0",
            args.warmup_s)
    warm = (10.0 if args.minutes >= 30 else args.minutes / 3.0) if args.warmup_s is None else (
        args.warmup_s / 60.0)
    machine = machine_record()
    with tempfile.TemporaryDirectory(prefix="roger-bench-soak-") as tmp:
        workdir = args.keep or Path(tmp)
        workdir.mkdir(parents=True, exist_ok=True)
        if not args.json:
            print(f"roger bench soak: {args.robots} robot(s) x {args.rate:g} Hz for "
                  f"{args.minutes:g} min, growth measured after {warm:g} min "
                  f"({describe(machine)})")
        out = _soak(workdir, args)
    samples = out["samples"]
    t_warm = warm * 60.0
    at_warm = next((s for s in samples if s["t_s"] >= t_warm), samples[-1])
    result = {
        "rss_growth_after_warmup_pct": _growth(samples, "rss_total_mb", t_warm),
        "rss_main_growth_after_warmup_pct": _growth(samples, "rss_main_mb", t_warm),
        "rss_workers_growth_after_warmup_pct": _growth(samples, "rss_workers_mb", t_warm),
        "rss_start_mb": samples[0]["rss_total_mb"], "rss_at_warmup_mb": at_warm["rss_total_mb"],
        "rss_end_mb": samples[-1]["rss_total_mb"], "rss_max_mb": max(
            s["rss_total_mb"] for s in samples),
        "updates_at_warmup": at_warm["updates"], "updates_end": samples[-1]["updates"],
        "target_growth_pct": TARGET_GROWTH_PCT,
        "checkpoints": out["checkpoints"], "samples": samples, "exit_code": out["exit_code"],
        "settings": {"stream": args.stream, "minutes": args.minutes, "warmup_minutes": warm,
                     "robots": args.robots,
                     "rate_hz": args.rate, "interval_s": args.interval,
                     "overrides": list(args.overrides)},
        "machine": finish(machine),
    }
    # a daemon that had to be killed (or crashed) at the end did not finish the run cleanly
    result["meets_target"] = bool(result["rss_growth_after_warmup_pct"] < TARGET_GROWTH_PCT
                                  and out["exit_code"] == 0)
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    print(f"RSS {result['rss_start_mb']:.1f} MB at start, {result['rss_at_warmup_mb']:.1f} MB "
          f"after warm-up, {result['rss_end_mb']:.1f} MB at the end: "
          f"{result['rss_growth_after_warmup_pct']:+.1f} % after warm-up (target < "
          f"{TARGET_GROWTH_PCT:g} %; loop {result['rss_main_growth_after_warmup_pct']:+.1f} %, "
          f"workers {result['rss_workers_growth_after_warmup_pct']:+.1f} %)")
    for r, ck in out["checkpoints"].items():
        if ck:
            print(f"{r}: checkpoint {ck['bytes'] / 1e6:.2f} MB at {ck['updates']} updates, "
                  f"{ck['distinct_experts']} distinct experts, "
                  f"{ck['bytes_per_expert'] / 1e3:.0f} kB per expert (+ history "
                  f"{ck['history_bytes'] / 1e3:.0f} kB)")
    if out["exit_code"] != 0:
        print(f"the daemon exited with {out['exit_code']} (-9: killed, it had not stopped 60 s "
              "after SIGTERM): target not met")
    return 0
