"""``roger bench NAME``: benchmarks that print a table, or one JSON object with ``--json``."""

from __future__ import annotations

import argparse

from roger_daemon.cli import BENCHES, dispatch
from roger_daemon.console import exit_on_sigterm

__all__ = ["configure", "run"]


def configure(parser: argparse.ArgumentParser) -> None:
    """Take the benchmark name and its own arguments verbatim."""
    parser.add_argument("name", choices=sorted(BENCHES), help="which benchmark")
    parser.add_argument("rest", nargs=argparse.REMAINDER, help="arguments of that benchmark")


def run(args: argparse.Namespace) -> int:
    """Run one benchmark through the same lazy dispatcher as the top-level command.

    SIGTERM ends it with exit status 143 after its daemons and clients are stopped."""
    exit_on_sigterm()
    return dispatch(BENCHES, "roger bench", [args.name, *args.rest])
