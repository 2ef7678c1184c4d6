"""``roger log info|recover|export``: inspect, salvage and convert session logs.

Exit codes: 0 ok; 1 recover kept nothing or the file is not MCAP; 3 recover was lossy (the
source had no footer or an unreadable tail; same meaning as ``mcap recover``).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

__all__ = ["configure", "run"]


def configure(parser: argparse.ArgumentParser) -> None:
    """Sub-commands info, recover, export."""
    sub = parser.add_subparsers(dest="log_command", metavar="ACTION")
    sub.required = True
    p = sub.add_parser("info", help="channels, counts, duration, rates, gaps, metadata")
    p.add_argument("file", type=Path, metavar="FILE", help="an MCAP session log")
    p.add_argument("--json", action="store_true", help="one JSON object on stdout")
    p = sub.add_parser("recover", help="salvage a footer-less file into a valid, indexed file")
    p.add_argument("file", type=Path, metavar="FILE", help="a footer-less (crashed) MCAP log")
    p.add_argument("--out", type=Path, help="output file (default FILE.recovered.mcap)")
    p.add_argument("--in-place", action="store_true",
                   help="replace FILE atomically (keeps the damaged one as FILE.damaged)")
    p.add_argument("--json", action="store_true", help="report as JSON")
    p = sub.add_parser("export", help="the session as json + jsonschema MCAP (opens in Foxglove)")
    p.add_argument("file", type=Path, metavar="FILE", help="an MCAP session log (msgpack)")
    p.add_argument("--out", type=Path, default=None, metavar="OUT",
                   help="output MCAP with json message encoding (default FILE.json.mcap)")
    p.add_argument("--json", action="store_true", help="report as JSON")


def run(args: argparse.Namespace) -> int:
    """Dispatch on the action."""
    if args.log_command == "info":
        return _info(args)
    if args.log_command == "recover":
        return _recover(args)
    return _export(args)


def _info(args: argparse.Namespace) -> int:
    from roger_daemon.recording.info import format_info, log_info

    if not args.file.is_file():
        print(f"roger log info: no such file {args.file}", file=sys.stderr)
        return 2
    info = log_info(args.file)
    text = json.dumps(info, indent=2, sort_keys=True) if args.json else format_info(info)
    try:
        print(text)
        sys.stdout.flush()
    except BrokenPipeError:  # `roger log info F | head`
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    return 0


def _recover(args: argparse.Namespace) -> int:
    from roger_daemon.recording.recover import recover, recover_in_place

    if args.in_place and args.out:
        print("roger log recover: --out and --in-place exclude each other", file=sys.stderr)
        return 2
    try:
        rep = (recover_in_place(args.file, keep_original=True) if args.in_place
               else recover(args.file, args.out))
    except (ValueError, OSError) as exc:
        print(f"roger log recover: {exc}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(rep.to_dict(), indent=2, sort_keys=True))
    else:
        state = "complete (had its footer)" if rep.complete and not rep.error else (
            f"salvaged; reading stopped: {rep.error or 'no footer'}")
        print(f"{rep.source}: {state}")
        print(f"kept {rep.messages} messages in {rep.chunks} chunks, {rep.channels} channels, "
              f"{rep.metadata} metadata records; dropped {rep.bytes_dropped} of "
              f"{rep.bytes_total} bytes")
        print(f"wrote {rep.output}")
    if rep.messages == 0 and rep.metadata == 0:
        return 1
    return 0 if rep.complete and not rep.error else 3


def _export(args: argparse.Namespace) -> int:
    from roger_daemon.recording.export import export_json

    try:
        rep = export_json(args.file, args.out or args.file.with_suffix(".json.mcap"))
    except (ValueError, OSError) as exc:
        print(f"roger log export: {exc}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps({"output": str(rep.output), "messages": rep.messages,
                          "channels": rep.channels, "skipped": dict(rep.skipped),
                          "source_complete": rep.source_complete,
                          "source_error": rep.source_error}, indent=2, sort_keys=True))
        return 0
    skipped = sum(rep.skipped.values())
    print(f"wrote {rep.output}: {rep.messages} JSON messages on {rep.channels} channels"
          + (f", skipped {skipped} non-msgpack payloads" if skipped else "")
          + ("" if rep.source_complete else f" (source incomplete: {rep.source_error})"))
    return 0
