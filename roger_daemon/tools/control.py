"""``roger control ROBOT mode MODE|reset|checkpoint``: a control request, confirmed.

Steps, each within ``--timeout``: wait for a status of ``ROBOT`` (proves that a daemon serves
it and that the two sessions see each other, so the request is not sent into the void); send
one ``Control`` whose ``stamp_ns`` identifies it; wait for the daemon's confirmation, a status
whose ``info.control_stamp_ns`` equals that stamp (the daemon publishes it as soon as it has
applied the request; ``protocols/README.md``, control). For ``checkpoint`` it then waits until
``info.checkpoints_written`` grows (the file is written in the background) and prints the path,
or fails if ``info.checkpoint_errors`` grows. Exit 0 when confirmed, 1 without confirmation
(the request may or may not have been applied: check ``roger status``), 2 for a bad request.
Every step is :class:`roger_daemon.client.RobotClient`'s (``request``, ``wait_checkpoint``):
the robot-side client's code, on the session the connection options open.
"""

from __future__ import annotations

import argparse
import sys
import time

from protocols import Status, keys
from protocols.errors import ProtocolError
from protocols.messages import MODES
from roger_daemon.client import RobotClient
from roger_daemon.tools.common import UsageError, add_connection_args, open_from_args

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


def run(args: argparse.Namespace) -> int:
    """Send the request and wait for its confirmation (through :class:`RobotClient`, the
    robot-side client, on the session the command line asked for)."""
    _check(args)
    session = open_from_args(args)
    try:
        with RobotClient(session=session, robot=args.robot, dims=None) as client:
            return _control(client, args)
    finally:
        session.close()


def _fail(text: str) -> int:
    print(f"roger control: {text}", file=sys.stderr)
    return 1


def _control(client: RobotClient, args: argparse.Namespace) -> int:
    deadline = time.monotonic() + float(args.timeout)

    def left() -> float:
        return max(deadline - time.monotonic(), 0.0)

    try:
        client.wait_status(timeout=left())
    except TimeoutError:
        return _fail(f"no daemon serving {args.robot!r} was heard within {args.timeout:g} s "
                     f"(nothing sent; see roger list)")
    try:
        ack = client.request(args.op, args.mode, timeout=left())
    except TimeoutError:
        return _fail(f"sent {args.op} to {args.robot} but the daemon did not confirm it within "
                     f"{args.timeout:g} s; it may or may not have been applied (roger status)")
    if args.op == "checkpoint":
        return _checkpoint_written(client, ack, left(), args)
    what = f"mode {ack.mode}" if args.op == "mode" else f"reset ({ack.updates} updates)"
    print(f"{args.robot}: {what}, confirmed by daemon {ack.daemon}")
    return 0


def _checkpoint_written(client: RobotClient, ack: Status, timeout: float,
                        args: argparse.Namespace) -> int:
    try:
        done = client.wait_checkpoint(ack, timeout)
    except TimeoutError:
        return _fail(f"the daemon accepted the checkpoint request but reported no checkpoint "
                     f"written within {args.timeout:g} s")
    except RuntimeError:
        return _fail("the daemon reported that the checkpoint failed (see its log)")
    print(f"{args.robot}: checkpoint {done.info.get('checkpoint')} "
          f"({done.info.get('checkpoint_updates')} updates), confirmed by daemon "
          f"{done.daemon}")
    return 0
