"""``roger echo KEY``: print the decoded messages published on a key expression.

One line per message: ``KEY: {fields}`` with floats rounded for reading, or with ``--json``
one JSON object per line ``{"key", "recv_ns", "msg"}`` with every field at full precision (for
``jq``). A payload that does not decode is reported on stderr with its rejection reason and
counted; the command goes on. Stops after ``--count`` messages, or ``--duration`` seconds, or
at Ctrl-C; exits 1 if ``--count`` was asked and not reached.
"""

from __future__ import annotations

import argparse
import sys
import time

from protocols.errors import ProtocolError
from roger_daemon.tools.common import (
    Listener,
    add_connection_args,
    count,
    decode_sample,
    dumps,
    invalid_text,
    key_expr,
    open_from_args,
    seconds,
)


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roger echo``."""
    parser.add_argument("key", metavar="KEY",
                        help="key expression, e.g. roger/aibo/status, aibo/prediction or "
                             "roger/*/status ('roger/' may be left out)")
    parser.add_argument("--json", action="store_true",
                        help="one JSON object per line, every field at full precision")
    parser.add_argument("--count", type=count, default=0, metavar="N",
                        help="stop after N messages (default: run until Ctrl-C)")
    parser.add_argument("--duration", type=seconds, default=0.0, metavar="S",
                        help="stop after S seconds (default: run until Ctrl-C)")
    add_connection_args(parser)


def run(args: argparse.Namespace) -> int:
    """Echo until done; 0, or 1 if ``--count`` messages did not arrive within ``--timeout``."""
    key = key_expr(args.key)
    session = open_from_args(args)
    listener = Listener(session, key)
    shown = bad = 0
    start = time.monotonic()
    last = start
    try:
        while not args.count or shown < args.count:
            now = time.monotonic()
            if args.duration and now - start >= args.duration:
                break
            if args.count and now - last >= args.timeout:
                break
            s = listener.get(0.2)
            if s is None:
                continue
            last = s.recv_s
            try:
                msg = decode_sample(s.key, s.payload)
            except ProtocolError as exc:
                bad += 1
                print(invalid_text(s.key, exc), file=sys.stderr)
                continue
            shown += 1
            if args.json:
                print(dumps({"key": s.key, "recv_ns": time.time_ns(), "msg": msg}), flush=True)
            else:
                print(f"{s.key}: {dumps(msg, digits=4)}", flush=True)
    finally:
        listener.close()
        session.close()
    if args.count and shown < args.count:
        print(f"roger echo: {shown} of {args.count} messages on {key} "
              f"({bad} invalid) before {args.timeout:g} s without one", file=sys.stderr)
        return 1
    return 0
