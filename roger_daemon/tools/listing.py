"""``roger list``: the daemons alive (by liveliness token), the robots each one serves, and
the robots heard on the network that no daemon serves.

A liveliness subscriber with history on ``roger/@daemon/*`` finds the daemons at once (the
tokens alive now are delivered on declaration; a query waited for its timeout); the robots a
daemon serves are the ones whose status (``roger/*/status``, 1 Hz) names it, and a robot whose
perception (``roger/*/perception``) is heard but whose status is not is listed as unserved.
Everything is heard at the same time, for ``--wait`` seconds (a little over one status
period), so the command takes about that long (up to ``--timeout`` while no daemon token has
come). A daemon whose token is alive but whose status
never came is shown with level ``STALE`` (its loop may be stuck). Exit status 1 when no daemon
and no robot was heard.
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
    parser.add_argument("--wait", type=seconds, default=1.2, metavar="S",
                        help="listen this long for the daemons' status to see which robots "
                             "they serve (default: 1.2, a little over one status period)")
    parser.add_argument("--json", action="store_true",
                        help="one JSON object: {daemons: [{id, level, robots: [{robot, level, "
                             "mode, updates}]}], unserved: [robot, ...]}")
    add_connection_args(parser, timeout=2.0)


def gather(listener: Listener, until: float) -> dict[str, dict[str, Any]]:
    """The newest status per robot received before ``until`` (monotonic seconds)."""
    out: dict[str, dict[str, Any]] = {}
    for st in listener.decoded(until):  # invalid ones: roger status/echo report those
        out[st["robot"]] = st
    return out


def _heard(inputs: Any) -> set[str]:
    """The robots of the samples waiting in the subscriber ``inputs`` (Zenoh's own
    ``RingChannel``: only drained at the end, so no queue of ours; docs/zenoh-notes.md §3.2)."""
    robots = set()
    while (s := inputs.try_recv()) is not None:
        robots.add(str(s.key_expr).split("/")[1])
    return robots


def run(args: argparse.Namespace) -> int:
    """Print the daemons, their robots and the unserved robots; 1 if nothing was heard."""
    import zenoh

    session = open_from_args(args)
    listener = Listener(session, keys.all_of_kind("status"))
    tokens = Listener(session, keys.daemon_liveliness_all(), liveliness=True, history=True)
    inputs = session.declare_subscriber(keys.all_of_kind("perception"),
                                        zenoh.handlers.RingChannel(1024))
    try:
        start = time.monotonic()
        statuses = gather(listener, start + args.wait)
        found = [tokens.get(0.0)]
        if found[0] is None:  # no daemon yet: wait for one token up to --timeout
            found = [tokens.get(max(start + args.timeout - time.monotonic(), 0.0))]
            if found[0] is not None:
                statuses.update(gather(listener, time.monotonic() + args.wait))
        found += list(iter(lambda: tokens.get(0.0), None))
        ids = sorted({s.key[len(TOKEN_PREFIX):] for s in found
                      if s is not None and s.key.startswith(TOKEN_PREFIX)})
        unserved = sorted(_heard(inputs) - set(statuses))
    finally:
        for li in (listener, tokens):
            li.close()
        inputs.undeclare()
        session.close()
    daemons: list[dict[str, Any]] = [{"id": d, "robots": [
        {"robot": r, "level": level_of(st), "mode": st["mode"], "updates": st["updates"]}
        for r, st in sorted(statuses.items()) if st["daemon"] == d]} for d in ids]
    for d in daemons:  # alive (token) but silent: its loop may be stuck
        d["level"] = "STALE" if not d["robots"] else worst([r["level"] for r in d["robots"]
                                                             if r["level"] in LEVELS])
    if args.json:
        print(dumps({"daemons": daemons, "unserved": unserved}))
    else:
        for d in daemons:
            robots = ", ".join(f"{r['robot']} ({r['level']}, {r['mode']}, {r['updates']} "
                               f"updates)" for r in d["robots"])
            print(f"{d['id']}  token {TOKEN_PREFIX}{d['id']}  robots: "
                  f"{robots or f'none heard within {args.wait:g} s (STALE?)'}")
        for r in unserved:
            print(f"robot {r}: publishes perceptions, no daemon's status names it (unserved)")
    if not ids:
        print(f"roger list: no daemon answered within {args.timeout:g} s", file=sys.stderr)
        return 1 if not unserved else 0
    return 0
