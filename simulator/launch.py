"""``roger up FILE``: daemon, simulator and controller from one TOML file, like a launch file.

The file names the processes and their roles (``configs/up-demonstration.toml`` is the
annotated example; ``roger config example up``); everything else is derived so that it fits:

- **Ports**: the daemon listens on ``ports.daemon``, the simulator on ``ports.sim`` and connects
  to the daemon, the controller connects to both (``0``: a free loopback port is picked). Every
  process is a peer on 127.0.0.1 with multicast scouting off.
- **Controller**: ``controller.role`` ``demonstrator`` (the daemon learns), ``transitioner``
  (the HCC picks among the learned experts) or ``play`` (``roger play``: no HCC at all, the
  learned transitions of the newest checkpoint in ``checkpoints/`` pick; the daemon serves it
  in predict mode; ``configs/up-play.toml``).
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
import sys
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from roger_daemon.console import UsageError
from roger_daemon.tools.common import port
from roger_daemon.zenoh_session import DAEMON_PORT
from simulator.supervise import Supervisor

__all__ = ["Plan", "configure", "plan", "run"]

log = logging.getLogger("roger.up")

TICK_HZ = 30.0
N_LOCATIONS = 13  # the AIBO task's start locations (simulator.episodes.START_LOCATIONS)
#: the controller's roles: ``roger hcc --role demonstrator|transitioner``, or ``roger play``
#: (no hand-coded controller: ROGER's experts and their learned transitions, docs/autonomy.md)
ROLES = ("demonstrator", "transitioner", "play")
SECTIONS = {"session", "ports", "daemon", "sim", "controller", "view"}


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roger up``."""
    parser.add_argument("file", type=Path, metavar="FILE",
                        help="launch file (TOML), e.g. configs/up-demonstration.toml")
    parser.add_argument("--dry-run", action="store_true",
                        help="print the command lines and the queue sizing, start nothing")
    for name, default in (("daemon", DAEMON_PORT), ("sim", 7450), ("view", 8765)):
        parser.add_argument(f"--{name}-port", type=port, default=None, metavar="PORT",
                            help=f"override the file's ports.{name} (its default {default}; "
                                 "0: a free one), e.g. to run two sessions side by side")


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
    pd, ps = _port(ports, "daemon", DAEMON_PORT), _port(ports, "sim", 7450)
    p.daemon_ep, sim_ep = f"tcp/127.0.0.1:{pd}", f"tcp/127.0.0.1:{ps}"
    p.max_pairs = math.ceil(_count_locations(locations) * episodes * time_limit * TICK_HZ)
    p.queue_size = _queue_size(dmn, p, clock, role)
    exe = [sys.executable, "-m", "roger_daemon"]
    daemon = [*exe, "daemon"]
    if "config" in dmn:
        daemon += ["--config", str((base / _get(dmn, "daemon", "config", str, "")).resolve())]
    if _get(dmn, "daemon", "fresh", bool, False):
        daemon.append("--fresh")
    mode = "learn+predict" if role == "demonstrator" else "predict"
    for s in [f"daemon.clock={json.dumps(clock)}", f"daemon.mode={json.dumps(mode)}",
              f"daemon.queue_size={p.queue_size}", f"zenoh.listen=[{json.dumps(p.daemon_ep)}]",
              "zenoh.connect=[]", "zenoh.multicast_scouting=false",
              'checkpoint.dir="checkpoints"', 'recording.dir="recordings"',
              *_strings(dmn, "daemon", "set")]:
        daemon += ["--set", s]
    p.argv["daemon"] = daemon
    # roger play reads the transitions of the checkpoint the daemon resumes (its newest)
    node = ["play", "--checkpoint", "checkpoints"] if role == "play" else ["hcc", "--role", role]
    p.argv["controller"] = [*exe, *node, "--clock", clock,
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
                     "--episode-duration", repr(time_limit), "--wait-peers", "2",
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
    return int(max(asked, p.max_pairs, 256))


def run(args: argparse.Namespace) -> int:
    """Start the processes, supervise them, stop them in order."""
    try:
        data = tomllib.loads(args.file.read_text(encoding="utf-8"))
    except OSError as exc:
        raise UsageError(f"cannot read the launch file {args.file}: {exc.strerror}") from None
    except tomllib.TOMLDecodeError as exc:
        raise UsageError(f"{args.file} is not valid TOML: {exc}") from None
    ports = dict(data.get("ports", {})) if isinstance(data.get("ports", {}), dict) else {}
    for name in ("daemon", "sim", "view"):
        given = getattr(args, f"{name}_port", None)
        if given is not None:
            ports[name] = given
    if ports:
        data = {**data, "ports": ports}
    p = plan(data, Path.cwd())
    for w in p.warnings:
        log.warning("%s", w)
    if args.dry_run:
        print(f"daemon queue_size {p.queue_size} for up to {p.max_pairs} pairs")
        for name, argv in p.argv.items():
            print(f"{name}: {shlex.join(argv)}")
        return 0
    try:
        return Supervisor(p).run()
    except RuntimeError as exc:
        log.error("%s", exc)
        return 1
