"""Fault drill (issue 55): a router, a daemon, the simulator and the HCC demonstrator, all Zenoh
clients of the router on 127.0.0.1, with the router killed (SIGKILL) and restarted every
``--kill-every`` seconds and the daemon stopped (SIGSTOP) for ``--stop-s`` seconds at each
``--stop-at``. What it measures (docs/zenoh-notes.md §8, *The fault drill*):

* **stalls while the router is up**: the longest gap between two perceptions reaching a
  client of the router (this script's own session), within the windows in which the router
  was up and had delivered again since its restart; the same for the daemon's predictions,
  outside the daemon's stops;
* **every lost perception counted**: the perceptions the simulator published (its results'
  ``ticks``) less those the daemon received (status ``ticks``), against the daemon's own
  count (``info.lost_in_transport``); with its link downs and stalls and the levels it said;
* **acknowledged pairs lost**: the daemon is killed (SIGKILL) at the end and started again;
  the ``updates`` of its first status against the most any prediction or status had
  acknowledged before (0 lost when the new one has at least as many).

    nice .venv/bin/python scripts/fault_drill.py --seconds 240 --out runs/fault_drill

prints one JSON object (also ``DIR/drill.json``); the processes' logs are in ``DIR``.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from collections import deque
from collections.abc import Sequence
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from protocols import decode, keys  # noqa: E402
from protocols.aibo import DIMS  # noqa: E402
from roger_daemon.atomic import OutputDirError, owned_output_dir  # noqa: E402
from roger_daemon.harness import DaemonProcess, free_port, write_config  # noqa: E402
from roger_daemon.zenoh_session import ZenohSettings, open_session  # noqa: E402

ROBOT = "aibo"
CLIENT = ("--listen", "none", "--zenoh-set", 'mode="client"')


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=600.0, help="drill length (default 600)")
    p.add_argument("--kill-every", type=float, default=120.0,
                   help="kill -9 the router this often (s, default 120)")
    p.add_argument("--outage-s", type=float, default=5.0,
                   help="restart the router this long after its kill (default 5)")
    p.add_argument("--stop-at", type=float, action="append", default=None,
                   help="SIGSTOP the daemon at this second (repeatable; default 180)")
    p.add_argument("--stop-s", type=float, default=5.0, help="each stop's length (default 5)")
    p.add_argument("--out", type=Path, default=Path("runs/fault_drill"),
                   help="directory for the logs and drill.json: created, or one an earlier "
                        "drill made (what that drill wrote is removed first)")
    args = p.parse_args(argv)
    if not (args.seconds > 0 and args.kill_every > args.outage_s > 0 and args.stop_s > 0):
        p.error(f"--seconds {args.seconds}, --kill-every {args.kill_every}, --outage-s "
                f"{args.outage_s}, --stop-s {args.stop_s}: need seconds > 0 and "
                "kill-every > outage-s > 0, stop-s > 0")
    args.stop_at = [180.0] if args.stop_at is None else args.stop_at
    return args


class Procs:
    """The drill's child processes, each with its log in the output directory."""

    def __init__(self, out: Path) -> None:
        self.out = out
        self.env = {**os.environ, "RUST_LOG": "error", "ROGER_LOG_LEVEL": "INFO"}
        self.running: dict[str, subprocess.Popen[bytes]] = {}
        self._logs: list[Any] = []

    def start(self, name: str, argv: Sequence[str]) -> subprocess.Popen[bytes]:
        log = open(self.out / f"{name}.log", "ab")  # closed in close()
        self._logs.append(log)
        proc = subprocess.Popen([sys.executable, "-m", "roger_daemon", *argv], cwd=ROOT,
                                env=self.env, stdout=log, stderr=subprocess.STDOUT)
        self.running[name] = proc
        return proc

    def stop(self, name: str, sig: int = signal.SIGTERM) -> None:
        proc = self.running.pop(name, None)
        if proc is not None and proc.poll() is None:
            proc.send_signal(sig)
            try:
                proc.wait(20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(10)

    def close(self) -> None:
        for name in list(self.running):
            proc = self.running[name]
            if proc.poll() is None:
                proc.send_signal(signal.SIGCONT)
            self.stop(name)
        for log in self._logs:
            log.close()


def wait_for(path: Path, text: str, timeout: float) -> None:
    end = time.monotonic() + timeout
    while text not in path.read_text(errors="replace"):
        if time.monotonic() > end:
            raise RuntimeError(f"{text!r} not in {path} after {timeout} s")
        time.sleep(0.1)


class Monitor:
    """A client of the router: when each perception arrived; each prediction and status."""

    def __init__(self, endpoint: str) -> None:
        self.arrivals: deque[tuple[str, float, bytes]] = deque()
        self.session = open_session(ZenohSettings(mode="client", connect=(endpoint,),
                                                  listen=None))
        for kind in ("perception", "prediction", "status"):
            self.session.declare_subscriber(keys.key(ROBOT, kind), self._on(kind))

    def _on(self, kind: str) -> Any:
        def arrived(sample: Any) -> None:  # a Zenoh thread: record only
            self.arrivals.append((kind, time.monotonic(), sample.payload.to_bytes()))
        return arrived

    def of(self, kind: str) -> list[tuple[float, Any]]:
        out = []
        for k, t, data in list(self.arrivals):
            if k == kind:
                out.append((t, decode(kind, data, dims=DIMS, robot=ROBOT)))
        return out

    def close(self) -> None:
        self.session.close()


def max_gap(times: Sequence[float], windows: Sequence[tuple[float, float]]) -> float:
    """The longest gap between consecutive ``times`` that lies within one of ``windows``."""
    worst = 0.0
    for a, b in zip(times, times[1:], strict=False):
        if any(lo <= a and b <= hi for lo, hi in windows):
            worst = max(worst, b - a)
    return round(worst, 3)


def start_all(procs: Procs, out: Path, endpoint: str, port: int) -> Path:
    procs.start("router", ["router", "--listen", endpoint])
    wait_for(out / "router.log", "listening on", 60)
    cfg = write_config(out / "daemon.toml", port=port, workdir=out,
                       daemon={"clock": "realtime"},
                       zenoh={"mode": "client", "connect": [endpoint]})
    cfg.write_text(cfg.read_text().replace(f'listen = ["{endpoint}"]\n', ""))
    return cfg


def drill(args: argparse.Namespace) -> dict[str, Any]:
    out: Path = args.out
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    procs = Procs(out)
    events: list[tuple[str, float]] = []
    try:
        cfg = start_all(procs, out, endpoint, port)
        daemon = DaemonProcess(cfg, log=out / "daemon.log")
        daemon.wait_ready()
        monitor = Monitor(endpoint)
        conn = ("--connect", endpoint, *CLIENT)
        procs.start("hcc", ["hcc", "--role", "demonstrator", "--clock", "realtime", *conn])
        procs.start("sim", ["sim", "--clock", "realtime", "--vision", "fast", "--locations",
                            "all", "--episodes-per-location", "1000", "--results",
                            str(out / "sim.json"), *conn])
        t0 = time.monotonic()
        events.append(("start", t0))
        run_schedule(args, procs, daemon, endpoint, t0, events)
        procs.stop("sim")
        time.sleep(3.0)  # the daemon's status after the last perception
        procs.stop("hcc")
        before = monitor.of("status")
        acked = max([m.updates for _, m in monitor.of("prediction")] +
                    [m.updates for _, m in before], default=0)
        daemon.kill()  # SIGKILL; then a new one from the same checkpoints and log
        events.append(("daemon_killed", time.monotonic()))
        again = DaemonProcess(cfg, log=out / "daemon2.log")
        again.wait_ready()
        after = wait_status(monitor, len(before))
        again.terminate()
        report = summarise(args, monitor, events, before, acked, after)
        monitor.close()
        return report
    finally:
        procs.close()


def run_schedule(args: argparse.Namespace, procs: Procs, daemon: DaemonProcess,
                 endpoint: str, t0: float, events: list[tuple[str, float]]) -> None:
    """Kill and restart the router, stop and continue the daemon, as planned."""
    plan: list[tuple[float, str]] = []
    k = args.kill_every
    while k < args.seconds - args.outage_s:
        plan += [(k, "router_killed"), (k + args.outage_s, "router_started")]
        k += args.kill_every
    for s in args.stop_at:
        if s + args.stop_s < args.seconds:
            plan += [(s, "daemon_stopped"), (s + args.stop_s, "daemon_continued")]
    for at, what in sorted(plan):
        time.sleep(max(0.0, t0 + at - time.monotonic()))
        if what == "router_killed":
            procs.stop("router", signal.SIGKILL)
        elif what == "router_started":
            procs.start("router", ["router", "--listen", endpoint])
        else:
            daemon.proc.send_signal(signal.SIGSTOP if what == "daemon_stopped"
                                    else signal.SIGCONT)
        events.append((what, time.monotonic()))
    time.sleep(max(0.0, t0 + args.seconds - time.monotonic()))
    events.append(("end", time.monotonic()))


def wait_status(monitor: Monitor, seen: int, timeout: float = 60.0) -> Any:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        statuses = monitor.of("status")
        if len(statuses) > seen:
            return statuses[-1][1]
        time.sleep(0.2)
    raise RuntimeError("no status from the restarted daemon")


def up_windows(events: list[tuple[str, float]], first_after: Any) -> list[tuple[float, float]]:
    """The windows in which the router was up and had delivered again since its start."""
    windows, lo = [], first_after(next(t for w, t in events if w == "start"))
    for what, t in events:
        if what == "router_killed" and lo is not None:
            windows.append((lo, t))
            lo = None
        elif what == "router_started":
            lo = first_after(t)
        elif what == "end" and lo is not None:
            windows.append((lo, t))
    return windows


def summarise(args: argparse.Namespace, monitor: Monitor, events: list[tuple[str, float]],
              before: list[tuple[float, Any]], acked: int, after: Any) -> dict[str, Any]:
    perc_t = [t for t, _ in monitor.of("perception")]
    pred_t = [t for t, _ in monitor.of("prediction")]

    def first_after(t: float) -> float | None:
        return next((a for a in perc_t if a > t), None)

    windows = up_windows(events, first_after)
    stops = [(t, t2) for (w, t), (w2, t2) in zip(events, events[1:], strict=False)
             if w == "daemon_stopped" and w2 == "daemon_continued"]
    pred_windows = [(lo, hi) for lo, hi in windows]
    for s, c in stops:  # predictions: outside the daemon's stops (and 1 s after each)
        pred_windows = [w for lo, hi in pred_windows
                        for w in ((lo, min(hi, s)), (max(lo, c + 1.0), hi)) if w[1] > w[0]]
    last = before[-1][1]
    sim = json.loads((args.out / "sim.json").read_text())["summary"]
    t0 = events[0][1]
    levels = []
    for t, st in before:
        entry = (st.info.get("level"), st.info.get("level_reasons"))
        if not levels or levels[-1][1:] != entry:
            levels.append((round(t - t0, 1), *entry))
    return {
        "seconds": args.seconds,
        "events": [(w, round(t - t0, 2)) for w, t in events],
        "max_perception_gap_s_router_up": max_gap(perc_t, windows),
        "max_prediction_gap_s_router_up_daemon_running": max_gap(pred_t, pred_windows),
        "router_up_windows_s": [(round(lo - t0, 1), round(hi - t0, 1)) for lo, hi in windows],
        "sim_ticks": sim["ticks"], "daemon_ticks": last.ticks,
        "lost_perceptions_true": sim["ticks"] - last.ticks,
        "lost_in_transport": last.info.get("lost_in_transport"),
        "link_downs": last.info.get("link_downs"), "loop_stalls": last.info.get("loop_stalls"),
        "dropped": last.dropped, "unpaired_actions": last.info.get("unpaired_actions"),
        "updates": last.updates, "acknowledged": acked, "updates_after_kill9": after.updates,
        "acknowledged_lost": max(0, acked - after.updates),
        "statuses_blaming_latency": sum("latency p99" in str(st.info.get("level_reasons"))
                                        for _, st in before),
        "said_again": [lv for lv in levels if "while the link was down" in str(lv[2])],
        "levels": levels,
    }


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        with owned_output_dir(args.out, "fault drill"):
            report = drill(args)
            text = json.dumps(report, indent=1)
            (args.out / "drill.json").write_text(text + "\n")
    except OutputDirError as exc:
        print(f"fault_drill: {exc}", file=sys.stderr)
        return 2
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
