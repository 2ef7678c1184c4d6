"""``roger log info|recover|export|import``: inspect, salvage, convert and import session logs.

Exit codes: 0 ok; 1 the input is not an MCAP file (missing, a directory, wrong magic) or
recover kept nothing; 2 bad arguments, or the output exists and ``--force`` was not given;
3 the source was incomplete (no footer: its writer was killed, so what the writer had not
flushed is not in it; and/or an unreadable tail was dropped; the report says which).
An output file is never overwritten without ``--force``; outputs are written atomically
(complete or absent). ``--out`` is a directory (:mod:`roger_daemon.recording.outputs`).
``export --format lerobot|parquet|hdf5`` and ``import`` are :mod:`roger_daemon.datasets.cli`.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

from roger_daemon.recording.outputs import bad_input, existing_output, output_file

__all__ = ["configure", "run"]


def configure(parser: argparse.ArgumentParser) -> None:
    """Sub-commands info, recover, export, import."""
    from roger_daemon.datasets import cli as datasets_cli

    sub = parser.add_subparsers(dest="log_command", metavar="ACTION")
    sub.required = True
    p = sub.add_parser("info", help="channels, counts, duration, rates, gaps, metadata")
    p.add_argument("file", type=Path, metavar="FILE", help="an MCAP session log")
    p.add_argument("--json", action="store_true", help="one JSON object on stdout")
    p = sub.add_parser("recover", help="salvage a footer-less file into a valid, indexed file")
    p.add_argument("file", type=Path, metavar="FILE", help="a footer-less (crashed) MCAP log")
    p.add_argument("--out", type=Path, metavar="DIR",
                   help="directory for the recovered file, named as FILE (default: "
                        "FILE.recovered.mcap beside FILE; --out FILE.mcap, the old form, is "
                        "deprecated but still works)")
    p.add_argument("--in-place", action="store_true",
                   help="replace FILE atomically (keeps the damaged one as FILE.damaged)")
    p.add_argument("--json", action="store_true", help="report as JSON")
    p.add_argument("--force", action="store_true", help="overwrite an existing --out file")
    datasets_cli.configure_export(sub.add_parser(
        "export", help="the session as a Foxglove-readable json MCAP, or its learned pairs as "
                       "a LeRobot v3, Parquet or HDF5 dataset"))
    datasets_cli.configure_import(sub.add_parser(
        "import", help="a dataset (LeRobot v3, or ROGER's Parquet / HDF5) as a session log the "
                       "daemon's tools learn from"))


def run(args: argparse.Namespace) -> int:
    """Dispatch on the action."""
    if args.log_command == "info":
        return _info(args)
    if args.log_command == "recover":
        return _recover(args)
    from roger_daemon.datasets import cli as datasets_cli

    if args.log_command == "import":
        return datasets_cli.run_import(args)
    if args.format != "json":
        return datasets_cli.run_export(args)
    return _export(args)


def _info(args: argparse.Namespace) -> int:
    from roger_daemon.recording.info import format_info, log_info

    if bad_input("info", args.file):
        return 1
    info = log_info(args.file)
    text = json.dumps(info, indent=2, sort_keys=True) if args.json else format_info(info)
    try:
        print(text)
        sys.stdout.flush()
    except BrokenPipeError:  # `roger log info F | head`
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    return 0


def _recover(args: argparse.Namespace) -> int:
    from roger_daemon.recording.recover import default_output, recover, recover_in_place

    if args.in_place and args.out:
        print("roger log recover: --out and --in-place exclude each other", file=sys.stderr)
        return 2
    if bad_input("recover", args.file):
        return 1
    target = output_file("log recover", args.out, default_output(args.file))
    if not args.in_place and existing_output("recover", target, args.force):
        return 2
    if not args.in_place and target.resolve() == args.file.resolve():
        print(f"roger log recover: the output {target} is the input; use --in-place",
              file=sys.stderr)
        return 2
    try:
        if not args.in_place:
            target.parent.mkdir(parents=True, exist_ok=True)
        rep = (recover_in_place(args.file, keep_original=True) if args.in_place
               else recover(args.file, target))
    except (ValueError, OSError) as exc:
        print(f"roger log recover: {exc}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(rep.to_dict(), indent=2, sort_keys=True))
    else:
        print(f"{rep.source}: {_state(rep)}")
        print(f"kept {rep.messages} messages in {rep.chunks} chunks, {rep.channels} channels, "
              f"{rep.metadata} metadata records; dropped {rep.bytes_dropped} of "
              f"{rep.bytes_total} bytes")
        print(f"wrote {rep.output}")
    if rep.messages == 0 and rep.metadata == 0:
        return 1
    return 0 if rep.complete and not rep.error else 3


def _state(rep: Any) -> str:
    if rep.complete and not rep.error:
        return "complete (had its footer)"
    if not rep.bytes_dropped:
        return ("incomplete: no footer (its writer was killed; what it had not flushed is not "
                "in the file); every byte on disk was readable and kept")
    return (f"incomplete: reading stopped at an unreadable tail ({rep.error or 'no footer'}); "
            "it is dropped")


def _export(args: argparse.Namespace) -> int:
    from roger_daemon.recording.export import export_json

    if bad_input("export", args.file):
        return 1
    out = output_file("log export", args.out, args.file.with_suffix(".json.mcap"))
    if existing_output("export", out, args.force):
        return 2
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        rep = export_json(args.file, out)
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
