"""``roger list``: the daemons alive (by liveliness token) and the robots each one serves.

A liveliness query for ``roger/@daemon/*`` finds the daemons; the robots a daemon serves are
the ones whose status (``roger/*/status``, 1 Hz) names it. The status subscriber is declared
before the query so that statuses arriving meanwhile count; after the query the command keeps
listening for ``--wait`` seconds (a little over one status period). A daemon whose token is
alive but whose status never came is shown with level ``STALE`` (its loop may be stuck).
Exit status 1 when no daemon answered.
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any

from protocols import keys
from roger_daemon.daemon.health import LEVELS, worst
from roger_daemon.tools.common import (
    Listener,
    add_connection_args,
    dumps,
    open_from_args,
    seconds,
)
from roger_daemon.tools.status import level_of

TOKEN_PREFIX = f"{keys.ROOT}/@daemon/"


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roger list``."""
    parser.add_argument("--wait", type=seconds, default=1.5, metavar="S",
                        help="listen this long for the daemons' status to see which robots "
                             "they serve (default: 1.5, a little over one status period)")
    parser.add_argument("--json", action="store_true",
                        help="one JSON object: {daemons: [{id, level, robots: [{robot, level, "
                             "mode, updates}]}]}")
    add_connection_args(parser, timeout=2.0)


def daemons_alive(session: Any, timeout: float) -> list[str]:
    """Ids of the daemons whose liveliness token answers a query within ``timeout`` s."""
    found = []
    for reply in session.liveliness().get(keys.daemon_liveliness_all(), timeout=timeout):
        if reply.ok is not None:
            key = str(reply.ok.key_expr)
            if key.startswith(TOKEN_PREFIX):
                found.append(key[len(TOKEN_PREFIX):])
    return sorted(set(found))


def gather(listener: Listener, until: float) -> dict[str, dict[str, Any]]:
    """The newest status per robot received before ``until`` (monotonic seconds)."""
    out: dict[str, dict[str, Any]] = {}
    for st in listener.decoded(until):  # invalid ones: roger status/echo report those
        out[st["robot"]] = st
    return out


def run(args: argparse.Namespace) -> int:
    """Print the daemons and their robots; 1 if none answered."""
    session = open_from_args(args)
    listener = Listener(session, keys.all_of_kind("status"))
    try:
        start = time.monotonic()
        ids = daemons_alive(session, args.timeout)
        statuses = gather(listener, max(start, time.monotonic()) + args.wait)
    finally:
        listener.close()
        session.close()
    daemons: list[dict[str, Any]] = [{"id": d, "robots": [
        {"robot": r, "level": level_of(st), "mode": st["mode"], "updates": st["updates"]}
        for r, st in sorted(statuses.items()) if st["daemon"] == d]} for d in ids]
    for d in daemons:  # alive (token) but silent: its loop may be stuck
        d["level"] = "STALE" if not d["robots"] else worst([r["level"] for r in d["robots"]
                                                             if r["level"] in LEVELS])
    if args.json:
        print(dumps({"daemons": daemons}))
    else:
        for d in daemons:
            robots = ", ".join(f"{r['robot']} ({r['level']}, {r['mode']}, {r['updates']} "
                               f"updates)" for r in d["robots"])
            print(f"{d['id']}  token {TOKEN_PREFIX}{d['id']}  robots: "
                  f"{robots or f'none heard within {args.wait:g} s (STALE?)'}")
    if not ids:
        print(f"roger list: no daemon answered within {args.timeout:g} s", file=sys.stderr)
        return 1
    return 0
