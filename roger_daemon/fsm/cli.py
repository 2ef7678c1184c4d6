"""``roger model fsm CHECKPOINT``: the learned automaton of a ``roger+fsm`` checkpoint.

Prints its states, transitions and their conditions (:mod:`roger_daemon.fsm.inspect`);
``--json`` prints them as JSON instead (a flag, as in every command: ``--json > OUT``),
``--png OUT`` draws the graph. ``CHECKPOINT`` is a daemon
checkpoint file, a checkpoint directory (the newest valid checkpoint of ``--robot``), or a
model ``state_dict`` ``.npz`` (docs/autonomy.md, *Reading the automaton*). Exit 2 for a path
that holds no learned transitions (the message says how to get them).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from roger_daemon.console import UsageError

__all__ = ["configure", "run"]


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roger model``."""
    sub = parser.add_subparsers(dest="what", metavar="WHAT", required=True)
    p = sub.add_parser("fsm", help="the learned transitions of a roger+fsm checkpoint",
                       description="the learned transitions of a roger+fsm checkpoint: states, "
                                   "transitions and their conditions")
    p.add_argument("checkpoint", type=Path, metavar="CHECKPOINT",
                   help="daemon checkpoint, checkpoint directory, or state_dict .npz")
    p.add_argument("--robot", default="aibo", help="robot of a checkpoint directory")
    p.add_argument("--json", action="store_true",
                   help="print the automaton as JSON (every transition) instead of the table")
    p.add_argument("--png", type=Path, metavar="OUT", help="draw the automaton here (PNG)")
    p.add_argument("--top", type=int, default=3, help="conditions per transition (default 3)")
    p.add_argument("--limit", type=int, default=40,
                   help="transitions printed, most frequent first (default 40)")


def run(args: argparse.Namespace) -> int:
    """Print (and write) the automaton."""
    from roger_daemon.fsm.controller import LearnedFSM
    from roger_daemon.fsm.inspect import describe, draw_fsm, format_fsm
    from roger_daemon.fsm.player import load_fsm_state

    if args.top < 1 or args.limit < 1:
        raise UsageError(f"--top and --limit must be integers >= 1, got {args.top} and "
                         f"{args.limit}")
    if not args.checkpoint.exists():
        raise UsageError(f"CHECKPOINT must be an existing file or directory, got "
                         f"{str(args.checkpoint)!r}")
    try:
        fsm = LearnedFSM.from_state_dict(load_fsm_state(args.checkpoint, args.robot))
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    desc = describe(fsm, top=args.top)
    if args.png is not None:
        draw_fsm(desc, args.png)
    if args.json:
        print(json.dumps(desc, indent=1))
        return 0
    print(format_fsm(desc, limit=args.limit))
    if args.png is not None:
        print(f"wrote {args.png}")
    return 0
