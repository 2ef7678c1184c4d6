"""``roger status [ROBOT]``: the daemon's status of one robot (or of every robot), readable.

Without ``--watch``: waits for the next status (published at 1 Hz, and at once after a control
request) of ``ROBOT``, or of every robot heard within a status period when no robot is named,
prints it and exits 0 (1 if none came within ``--timeout``); a robot with a hot standby has a
status from each daemon, each printed with its role (docs/daemon.md, *Hot standby*). With
``--watch``: prints every status as it arrives until Ctrl-C, and a ``STALE`` line when a
robot's status stops coming (:func:`roger_daemon.daemon.health.is_stale`). ``--json``: one
JSON object per status, the message's fields plus ``level`` (``OK``/``WARN``/``ERROR``/
``STALE``) and ``age_s``.
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any

from protocols import keys
from protocols.errors import ProtocolError
from roger_daemon.daemon.health import is_stale
from roger_daemon.tools.common import (
    Listener,
    Sample,
    UsageError,
    add_connection_args,
    dumps,
    invalid_text,
    open_from_args,
)

STATUS_HZ = 1.0  # the daemon's default status rate; staleness is judged against it
GATHER_S = 1.2  # listen this long after the first status for the others (robots, daemons)


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roger status``."""
    parser.add_argument("robot", nargs="?", default=None, metavar="ROBOT",
                        help="robot id (default: every robot whose status is heard)")
    parser.add_argument("--watch", action="store_true",
                        help="keep printing every status (and STALE when they stop) until "
                             "Ctrl-C")
    parser.add_argument("--json", action="store_true",
                        help="one JSON object per status: its fields plus level and age_s")
    add_connection_args(parser)


def level_of(st: dict[str, Any]) -> str:
    """The level a status carries (``info.level``; ``?`` from a daemon that predates it)."""
    return str(st.get("info", {}).get("level", "?"))


def describe(st: dict[str, Any]) -> str:
    """Two readable lines for one status map."""
    info = st.get("info", {})
    reasons = info.get("level_reasons", "")
    lines = [
        f"{st['robot']}  {level_of(st)}  daemon {st['daemon']}{_role(info)}  mode {st['mode']}"
        f"  up {st['uptime_s']:.0f} s",
        f"  ticks {st['ticks']}  updates {st['updates']} ({st['updates_per_s']:.1f}/s)  "
        f"experts {st['experts']}  queue {st['queue_depth']}  dropped {st['dropped']}  "
        f"latency p50/p99 {st['latency_ms_p50']:.1f}/{st['latency_ms_p99']:.1f} ms",
    ]
    if info.get("pairs_teacher") or info.get("pairs_robot"):
        lines.append(f"  pairs from the teacher {info.get('pairs_teacher', 0)}, from the robot "
                     f"{info.get('pairs_robot', 0)}; corrections {info.get('corrections', 0)}")
    if info.get("lost_in_transport") or info.get("link_downs") or info.get("loop_stalls"):
        lines.append(f"  lost in transport {info.get('lost_in_transport', 0)}; link "
                     f"{info.get('link_state', '?')}, {info.get('link_downs', 0)} down "
                     f"(last outage {float(info.get('link_outage_s', 0)):.1f} s); stalls "
                     f"{info.get('loop_stalls', 0)}")
    if st.get("invalid"):
        lines.append("  invalid " + ", ".join(f"{k} {v}" for k, v in st["invalid"].items()))
    if info.get("checkpoint"):
        lines.append(f"  checkpoint {info['checkpoint']} ({info.get('checkpoint_updates')} "
                     f"updates)")
    if reasons:
        lines.append(f"  {level_of(st)}: {reasons}")
    return "\n".join(lines)


def _role(info: dict[str, Any]) -> str:
    """`` (standby of D)`` / `` (primary, took over N times)``: a hot standby's role."""
    role = info.get("role")
    if role == "standby":
        sync = "" if info.get("standby_in_sync", True) else \
            f", {info.get('standby_missing')} pairs missing"
        return f" (standby of {info.get('served_by') or 'nobody'}{sync})"
    if role == "primary" and info.get("takeovers"):
        return f" (primary, took over {info['takeovers']} times)"
    return f" ({role})" if role else ""


def _emit(st: dict[str, Any], as_json: bool, age_s: float = 0.0) -> None:
    if as_json:
        print(dumps({**st, "level": level_of(st), "age_s": round(age_s, 3)}), flush=True)
    else:
        print(describe(st), flush=True)


def _next_status(listener: Listener, timeout: float) -> dict[str, Any] | None:
    def report(s: Sample, exc: ProtocolError) -> None:
        print(invalid_text(s.key, exc), file=sys.stderr)

    return next(listener.decoded(time.monotonic() + timeout, report), None)


def run(args: argparse.Namespace) -> int:
    """Print status once (or ``--watch``); 1 if no status came within ``--timeout``."""
    if args.robot is not None:
        try:
            keys.validate_robot_id(args.robot)
        except ProtocolError as exc:
            raise UsageError(f"ROBOT: {exc.detail}") from None
    key = keys.status(args.robot) if args.robot else keys.all_of_kind("status")
    session = open_from_args(args)
    listener = Listener(session, key)
    try:
        if args.watch:
            return _watch(listener, args)
        first = _next_status(listener, args.timeout)
        if first is None:
            who = f"robot {args.robot!r}" if args.robot else "any robot"
            print(f"roger status: no status from {who} within {args.timeout:g} s; is a daemon "
                  f"running and reachable (roger list)?", file=sys.stderr)
            return 1
        found = {(first["robot"], first["daemon"]): first}  # a standby's status too
        end = time.monotonic() + GATHER_S
        while (st := _next_status(listener, end - time.monotonic())) is not None:
            found.setdefault((st["robot"], st["daemon"]), st)
        for robot_daemon in sorted(found):
            _emit(found[robot_daemon], args.json)
        return 0
    finally:
        listener.close()
        session.close()


def _watch(listener: Listener, args: argparse.Namespace) -> int:
    seen: dict[str, tuple[float, dict[str, Any]]] = {}
    stale: set[str] = set()
    heard = False
    start = time.monotonic()
    while True:
        st = _next_status(listener, 0.5)
        now = time.monotonic()
        if st is not None:
            heard = True
            seen[st["robot"]] = (now, st)
            stale.discard(st["robot"])
            _emit(st, args.json)
        for robot, (at, last) in seen.items():
            if robot not in stale and is_stale(now - at, STATUS_HZ):
                stale.add(robot)
                info = {**last.get("info", {}), "level": "STALE",
                        "level_reasons": f"no status for {now - at:.1f} s"}
                _emit({**last, "info": info}, args.json, now - at)
        if not heard and now - start >= args.timeout:
            print(f"roger status: no status within {args.timeout:g} s; still watching",
                  file=sys.stderr)
            heard = True
