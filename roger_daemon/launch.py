"""``roger up FILE``: daemon, simulator and controller from one TOML file, like a launch file.

The file names the processes and their roles (``configs/up-demonstration.toml`` is the
annotated example; ``roger config example up``); everything else is derived so that it fits:

- **Ports**: the daemon listens on ``ports.daemon``, the simulator on ``ports.sim`` and connects
  to the daemon, the controller connects to both (``0``: a free loopback port is picked). Every
  process is a peer on 127.0.0.1 with multicast scouting off.
- **Clock**: the daemon runs the simulator's clock (a lockstep transitioner waits for
  prediction(t), which only a lockstep daemon publishes for every perception).
- **Queue**: in lockstep the simulator runs as fast as the controller answers, not as fast as
  the daemon learns, so pairs pile up in the daemon's training queue. ``daemon.queue_size`` is
  raised to the session's worst case (episodes x time limit x 30 Hz; :func:`plan`) so that no
  pair is dropped; a file that sets a smaller one explicitly gets a warning at start, and
  while running the daemon's status is watched and any drop is logged as a warning.
- **Files**: every process runs in ``session.dir`` and logs to ``<name>.log`` there; the
  daemon's checkpoints and recordings go to ``checkpoints/`` and ``recordings/`` in it (a
  ``daemon.set`` entry may move them; relative paths in ``args`` are relative to it too).
  ``session.dir`` and ``daemon.config`` are relative to the working directory.
- **View**: with ``[view] enabled = true`` a ``roger view`` process serves the session on
  Foxglove's WebSocket (``ports.view``, default 8765) and the simulator publishes its ground
  truth (``--truth``) for the 3D scene; ``view.record`` also writes it to an MCAP file.
- **Order and stop**: daemon (until its ``ready`` log line), controller, view, simulator.
  When the simulator has run its episodes (``session.exit_when_done``, default true), or on
  Ctrl-C / SIGTERM, the processes are stopped in reverse order with SIGTERM (the daemon
  writes its final checkpoint; when the simulator finished, the daemon first gets up to
  ``session.learn_timeout_s`` to learn the pairs still queued), each given
  ``session.stop_timeout_s`` before SIGKILL. Children run in
  their own process groups, so a terminal's Ctrl-C reaches only this launcher, which stops
  them in order. Exit status 0 when every process stopped cleanly, 1 otherwise, 2 for a bad
  file.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import shlex
import signal
import subprocess
import sys
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType
from typing import IO, Any

from roger_daemon.console import UsageError

__all__ = ["Plan", "configure", "plan", "run"]

log = logging.getLogger("roger.up")

TICK_HZ = 30.0
N_LOCATIONS = 13  # the AIBO task's start locations (simulator.episodes.START_LOCATIONS)
ROLES = ("demonstrator", "transitioner")
SECTIONS = {"session", "ports", "daemon", "sim", "controller", "view"}


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roger up``."""
    parser.add_argument("file", type=Path, metavar="FILE",
                        help="launch file (TOML), e.g. configs/up-demonstration.toml")
    parser.add_argument("--dry-run", action="store_true",
                        help="print the command lines and the queue sizing, start nothing")


@dataclass
class Plan:
    """The processes to start, in order, with their command lines."""

    workdir: Path
    daemon_ep: str
    argv: dict[str, list[str]] = field(default_factory=dict)  # name -> argv, in start order
    queue_size: int = 0
    max_pairs: int = 0
    warnings: list[str] = field(default_factory=list)
    exit_when_done: bool = True
    stop_timeout_s: float = 30.0
    learn_timeout_s: float = 600.0


def _table(data: dict[str, Any], name: str) -> dict[str, Any]:
    value = data.get(name, {})
    if not isinstance(value, dict):
        raise UsageError(f"[{name}] must be a table, got {value!r}")
    return value


def _get(table: dict[str, Any], section: str, key: str, kind: type | tuple[type, ...],
         default: Any) -> Any:
    value = table.get(key, default)
    if isinstance(value, bool) and kind is not bool:
        ok = False
    else:
        ok = isinstance(value, kind)
    if not ok:
        want = kind.__name__ if isinstance(kind, type) else " or ".join(k.__name__ for k in kind)
        raise UsageError(f"{section}.{key} must be {want}, got {value!r}")
    return value


def _port(ports: dict[str, Any], name: str, default: int) -> int:
    value = _get(ports, "ports", name, int, default)
    if not 0 <= value <= 65535:
        raise UsageError(f"ports.{name} must be 0 (pick a free one) or 1-65535, got {value}")
    if value == 0:
        from roger_daemon.harness import free_port

        return free_port()
    return int(value)


def _count_locations(spec: str) -> int:
    from simulator.episodes import parse_locations

    try:
        return len(parse_locations(spec))
    except ValueError as exc:
        raise UsageError(f"sim.locations: {exc}") from None


def _strings(table: dict[str, Any], section: str, key: str) -> list[str]:
    value = _get(table, section, key, list, [])
    if not all(isinstance(v, str) for v in value):
        raise UsageError(f"{section}.{key} must be a list of strings, got {value!r}")
    return list(value)


def plan(data: dict[str, Any], base: Path) -> Plan:
    """The command lines for the launch file's ``data`` (relative paths against ``base``, the
    working directory, as in the daemon's config)."""
    unknown = set(data) - SECTIONS
    if unknown:
        raise UsageError(f"unknown table(s) {sorted(unknown)}; expected {sorted(SECTIONS)}")
    session, ports = _table(data, "session"), _table(data, "ports")
    dmn, sim, ctl = _table(data, "daemon"), _table(data, "sim"), _table(data, "controller")
    view = _table(data, "view")
    role = _get(ctl, "controller", "role", str, "demonstrator")
    if role not in ROLES:
        raise UsageError(f"controller.role must be one of {', '.join(ROLES)}, got {role!r}")
    clock = _get(sim, "sim", "clock", str, "lockstep")
    if clock not in ("lockstep", "realtime"):
        raise UsageError(f"sim.clock must be lockstep or realtime, got {clock!r}")
    time_limit = float(_get(sim, "sim", "time_limit", (int, float), 150.0))
    episodes = int(_get(sim, "sim", "episodes_per_location", int, 1))
    if not (math.isfinite(time_limit) and time_limit > 0) or episodes < 1:
        raise UsageError(f"sim.time_limit must be > 0 and sim.episodes_per_location >= 1, got "
                         f"{time_limit} and {episodes}")
    locations = str(_get(sim, "sim", "locations", str, "all"))
    p = Plan(workdir=(base / _get(session, "session", "dir", str, "runs/up")).resolve(),
             daemon_ep="")
    p.exit_when_done = _get(session, "session", "exit_when_done", bool, True)
    p.stop_timeout_s = float(_get(session, "session", "stop_timeout_s", (int, float), 30.0))
    p.learn_timeout_s = float(_get(session, "session", "learn_timeout_s", (int, float), 600.0))
    pd, ps = _port(ports, "daemon", 7447), _port(ports, "sim", 7450)
    p.daemon_ep, sim_ep = f"tcp/127.0.0.1:{pd}", f"tcp/127.0.0.1:{ps}"
    p.max_pairs = math.ceil(_count_locations(locations) * episodes * time_limit * TICK_HZ)
    p.queue_size = _queue_size(dmn, p, clock, role)
    exe = [sys.executable, "-m", "roger_daemon"]
    daemon = [*exe, "daemon"]
    if "config" in dmn:
        daemon += ["--config", str((base / _get(dmn, "daemon", "config", str, "")).resolve())]
    if _get(dmn, "daemon", "fresh", bool, False):
        daemon.append("--fresh")
    mode = "predict" if role == "transitioner" else "learn+predict"
    for s in [f"daemon.clock={json.dumps(clock)}", f"daemon.mode={json.dumps(mode)}",
              f"daemon.queue_size={p.queue_size}", f"zenoh.listen=[{json.dumps(p.daemon_ep)}]",
              "zenoh.connect=[]", "zenoh.multicast_scouting=false",
              'checkpoint.dir="checkpoints"', 'recording.dir="recordings"',
              *_strings(dmn, "daemon", "set")]:
        daemon += ["--set", s]
    p.argv["daemon"] = daemon
    p.argv["controller"] = [*exe, "hcc", "--role", role, "--clock", clock,
                            "--connect", sim_ep, "--connect", p.daemon_ep,
                            "--exit-when-done", *_strings(ctl, "controller", "args")]
    viewing = _get(view, "view", "enabled", bool, False)
    if viewing:  # before the simulator, so that it sees the first episode
        p.argv["view"] = [*exe, "view", "--port", str(_port(ports, "view", 8765)),
                          "--connect", p.daemon_ep, "--connect", sim_ep]
        if "record" in view:
            p.argv["view"] += ["--record", _get(view, "view", "record", str, "")]
    p.argv["sim"] = [*exe, "sim", "--clock", clock, "--listen", sim_ep,
                     "--connect", p.daemon_ep, "--locations", locations,
                     "--episodes-per-location", str(episodes),
                     "--time-limit", repr(time_limit), "--wait-peers", "2",
                     *(["--truth"] if viewing or _get(sim, "sim", "truth", bool, False) else []),
                     *_strings(sim, "sim", "args")]
    return p


def _queue_size(dmn: dict[str, Any], p: Plan, clock: str, role: str) -> int:
    """The training queue that holds every pair of the session (see the module docstring)."""
    asked = _get(dmn, "daemon", "queue_size", int, 0)
    if role != "demonstrator":
        return asked or 256  # predict mode: nothing is learned, nothing queues
    if asked and asked < p.max_pairs:
        p.warnings.append(
            f"daemon.queue_size = {asked} is smaller than the {p.max_pairs} pairs this "
            f"{clock} demonstration can produce: if learning falls behind, pairs will be "
            f"dropped (leave queue_size out to have it sized)")
        return int(asked)
    return max(asked, p.max_pairs, 256)


def run(args: argparse.Namespace) -> int:
    """Start the processes, supervise them, stop them in order."""
    try:
        data = tomllib.loads(args.file.read_text(encoding="utf-8"))
    except OSError as exc:
        raise UsageError(f"cannot read the launch file {args.file}: {exc.strerror}") from None
    except tomllib.TOMLDecodeError as exc:
        raise UsageError(f"{args.file} is not valid TOML: {exc}") from None
    p = plan(data, Path.cwd())
    for w in p.warnings:
        log.warning("%s", w)
    if args.dry_run:
        print(f"daemon queue_size {p.queue_size} for up to {p.max_pairs} pairs")
        for name, argv in p.argv.items():
            print(f"{name}: {shlex.join(argv)}")
        return 0
    try:
        return _Supervisor(p).run()
    except RuntimeError as exc:
        log.error("%s", exc)
        return 1


class _Supervisor:
    def __init__(self, p: Plan) -> None:
        self.p = p
        self.procs: dict[str, subprocess.Popen[bytes]] = {}
        self.logs: list[IO[bytes]] = []
        self.stop_reason = ""
        self.signalled = ""

    def _on_signal(self, signum: int, _frame: FrameType | None) -> None:
        self.signalled = self.stop_reason = signal.Signals(signum).name

    def run(self) -> int:
        self.p.workdir.mkdir(parents=True, exist_ok=True)
        old = {s: signal.signal(s, self._on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            self._start_all()
            if not self.stop_reason:
                self._supervise()
        finally:
            codes = self._stop_all()
            for s, h in old.items():
                signal.signal(s, h)
        bad = {n: c for n, c in codes.items() if c != 0}
        for name, code in codes.items():
            log.info("%s exited with %s", name, code)
        if bad:
            log.error("not every process stopped cleanly: %s (logs in %s)", bad, self.p.workdir)
            return 1
        log.info("stopped cleanly (%s); logs in %s", self.stop_reason or "done", self.p.workdir)
        return 0

    def _start(self, name: str) -> None:
        from simulator.experiment.procs import child_env

        handle = open(self.p.workdir / f"{name}.log", "wb")  # noqa: SIM115 - closed in stop
        self.logs.append(handle)
        self.procs[name] = subprocess.Popen(
            self.p.argv[name], stdout=handle, stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL, env=child_env(), start_new_session=True,
            cwd=self.p.workdir)
        log.info("started %s (pid %d): %s", name, self.procs[name].pid,
                 shlex.join(self.p.argv[name][2:]))

    def _start_all(self) -> None:
        self._start("daemon")
        self._wait_daemon()
        for name in [n for n in self.p.argv if n != "daemon"]:
            if self.stop_reason:
                return
            self._start(name)

    def _wait_daemon(self, timeout: float = 120.0) -> None:
        text = b" ready: "
        path = self.p.workdir / "daemon.log"
        end = time.monotonic() + timeout
        while time.monotonic() < end and not self.stop_reason:
            if text in path.read_bytes():
                log.info("daemon ready on %s; watch it with: roger status --watch --connect %s",
                         self.p.daemon_ep, self.p.daemon_ep)
                return
            if self.procs["daemon"].poll() is not None:
                raise RuntimeError(f"the daemon exited with {self.procs['daemon'].returncode}; "
                                   f"see {path}")
            time.sleep(0.1)
        if not self.stop_reason:
            raise RuntimeError(f"the daemon was not ready within {timeout:.0f} s; see {path}")

    def _supervise(self) -> None:
        watch = _DaemonWatch(self.p.daemon_ep)
        try:
            while not self.stop_reason:
                watch.poll()
                for name, proc in self.procs.items():
                    if proc.poll() is None:
                        continue
                    if name == "sim" and proc.returncode == 0:
                        if self.p.exit_when_done:
                            self.stop_reason = "the session is over (the simulator finished)"
                            break
                    elif name == "controller" and proc.returncode == 0:
                        continue  # --exit-when-done: it saw the simulator's end
                    else:
                        self.stop_reason = f"{name} exited with {proc.returncode}"
                        break
                time.sleep(0.2)
            if not self.signalled and self.procs["daemon"].poll() is None:
                self._drain(watch)
        finally:
            watch.close()
        log.info("stopping: %s", self.stop_reason)

    def _drain(self, watch: _DaemonWatch) -> None:
        """Let the daemon learn the pairs still queued (lockstep runs ahead of learning)."""
        end = time.monotonic() + self.p.learn_timeout_s
        start, note = watch.received, time.monotonic()
        while time.monotonic() < end and not self.signalled:
            watch.poll()
            if watch.received > start and not any(watch.queue.values()):
                return
            if self.procs["daemon"].poll() is not None:
                return
            if time.monotonic() >= note:
                note = time.monotonic() + 10.0
                log.info("waiting for the daemon to learn its queued pairs: %s (at most %.0f s "
                         "more; Ctrl-C stops now, the checkpoint keeps them)",
                         ", ".join(f"{r}: {q} pairs or messages waiting, {watch.updates[r]} learned"
                                   for r, q in watch.queue.items()) or "no status yet",
                         end - time.monotonic())
            time.sleep(0.2)
        if not self.signalled:
            log.warning("the daemon still had queued pairs after %.0f s (session.learn_timeout_s);"
                        " they are saved in its final checkpoint", self.p.learn_timeout_s)

    def _stop_all(self) -> dict[str, int | None]:
        codes: dict[str, int | None] = {}
        for name in reversed(list(self.procs)):
            proc = self.procs[name]
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
                try:
                    proc.wait(self.p.stop_timeout_s)
                except subprocess.TimeoutExpired:
                    log.error("%s did not stop within %.0f s of SIGTERM: killed", name,
                              self.p.stop_timeout_s)
                    proc.kill()
                    proc.wait(10)
            codes[name] = proc.returncode
        for handle in self.logs:
            handle.close()
        return codes


class _DaemonWatch:
    """Follows the daemon's status: warns about drops and inbox overflow, keeps queue depths."""

    def __init__(self, endpoint: str) -> None:
        from protocols import keys
        from roger_daemon.config import ZenohSettings
        from roger_daemon.tools.common import Listener
        from roger_daemon.transport import open_session

        self.session = open_session(ZenohSettings(listen=(), connect=(endpoint,)))
        self.listener = Listener(self.session, keys.all_of_kind("status"), capacity=64)
        self.seen: dict[str, tuple[int, int]] = {}
        self.queue: dict[str, int] = {}
        self.updates: dict[str, int] = {}
        self.received = 0

    def poll(self) -> None:
        from protocols.errors import ProtocolError
        from roger_daemon.tools.common import decode_sample

        while (s := self.listener.get(0)) is not None:
            try:
                st = decode_sample(s.key, s.payload)
            except ProtocolError:
                continue
            now = (int(st["dropped"]), int(st["info"].get("inbox_overflow", 0)))
            before = self.seen.get(st["robot"], (0, 0))
            if now[0] > before[0] or now[1] > before[1]:
                log.warning("%s: the daemon dropped %d pairs (inbox overflow %d) so far: its "
                            "queue is too small for this session", st["robot"], *now)
            self.seen[st["robot"]] = now
            # pairs still to learn: queued, or not even paired yet (waiting in the inbox)
            self.queue[st["robot"]] = int(st["queue_depth"]) + int(
                st["info"].get("inbox_depth", 0))
            self.updates[st["robot"]] = int(st["updates"])
            self.received += 1

    def close(self) -> None:
        self.listener.close()
        self.session.close()
