"""``roger control ROBOT mode MODE|reset|checkpoint``: a control request, confirmed.

Steps, each within ``--timeout``: wait for a status of ``ROBOT`` (proves that a daemon serves
it and that the two sessions see each other, so the request is not sent into the void); send
one ``Control`` whose ``stamp_ns`` identifies it; wait for the daemon's confirmation, a status
whose ``info.control_stamp_ns`` equals that stamp (the daemon publishes it as soon as it has
applied the request; ``protocols/README.md``, control). For ``checkpoint`` it then waits until
``info.checkpoints_written`` grows (the file is written in the background) and prints the path,
or fails if ``info.checkpoint_errors`` grows. Exit 0 when confirmed, 1 without confirmation
(the request may or may not have been applied: check ``roger status``), 2 for a bad request.
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any

from protocols import Control, encode, keys
from protocols.errors import ProtocolError
from protocols.messages import MODES
from roger_daemon.client import checkpoint_outcome
from roger_daemon.tools.common import (
    Listener,
    UsageError,
    add_connection_args,
    open_from_args,
)

OPS = ("mode", "reset", "checkpoint")


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roger control``."""
    parser.add_argument("robot", metavar="ROBOT", help="robot id, e.g. aibo")
    parser.add_argument("op", metavar="OP", choices=OPS,
                        help="mode (with MODE), reset (forget everything learned) or "
                             "checkpoint (write one now)")
    parser.add_argument("mode", nargs="?", default="", metavar="MODE",
                        help=f"with OP mode: one of {', '.join(MODES)}")
    add_connection_args(parser, timeout=10.0)


def _check(args: argparse.Namespace) -> None:
    try:
        keys.validate_robot_id(args.robot)
    except ProtocolError as exc:
        raise UsageError(f"ROBOT: {exc.detail}") from None
    if args.op == "mode" and args.mode not in MODES:
        raise UsageError(f"control mode needs MODE, one of {', '.join(MODES)}; "
                         f"got {args.mode or 'nothing'!r}")
    if args.op != "mode" and args.mode:
        raise UsageError(f"control {args.op} takes no MODE, got {args.mode!r}")


def _wait(listener: Listener, deadline: float, pred: Any) -> dict[str, Any] | None:
    return next((st for st in listener.decoded(deadline) if pred(st)), None)


def run(args: argparse.Namespace) -> int:
    """Send the request and wait for its confirmation."""
    _check(args)
    session = open_from_args(args)
    listener = Listener(session, keys.status(args.robot))
    try:
        return _control(session, listener, args)
    finally:
        listener.close()
        session.close()


def _fail(text: str) -> int:
    print(f"roger control: {text}", file=sys.stderr)
    return 1


def _control(session: Any, listener: Listener, args: argparse.Namespace) -> int:
    import zenoh

    deadline = time.monotonic() + args.timeout
    if _wait(listener, deadline, lambda st: True) is None:
        return _fail(f"no daemon serving {args.robot!r} was heard within {args.timeout:g} s "
                     f"(nothing sent; see roger list)")
    msg = Control(args.robot, 0, 0.0, op=args.op, mode=args.mode)
    session.put(keys.control(args.robot), encode(msg),
                congestion_control=zenoh.CongestionControl.BLOCK, express=True)
    ack = _wait(listener, deadline,
                lambda st: st["info"].get("control_stamp_ns") == msg.stamp_ns)
    if ack is None:
        return _fail(f"sent {args.op} to {args.robot} but the daemon did not confirm it within "
                     f"{args.timeout:g} s; it may or may not have been applied (roger status)")
    if args.op == "checkpoint":
        return _checkpoint_written(listener, deadline, ack, args)
    what = f"mode {ack['mode']}" if args.op == "mode" else f"reset ({ack['updates']} updates)"
    print(f"{args.robot}: {what}, confirmed by daemon {ack['daemon']}")
    return 0


def _checkpoint_written(listener: Listener, deadline: float, ack: dict[str, Any],
                        args: argparse.Namespace) -> int:
    done = _wait(listener, deadline,
                 lambda st: checkpoint_outcome(ack["info"], st["info"]) is not None)
    if done is None:
        return _fail(f"the daemon accepted the checkpoint request but reported no checkpoint "
                     f"written within {args.timeout:g} s")
    if checkpoint_outcome(ack["info"], done["info"]) == "failed":
        return _fail("the daemon reported that the checkpoint failed (see its log)")
    print(f"{args.robot}: checkpoint {done['info'].get('checkpoint')} "
          f"({done['info'].get('checkpoint_updates')} updates), confirmed by daemon "
          f"{done['daemon']}")
    return 0
