"""The recorder's and the replay publisher's Zenoh defaults, on :mod:`roger_daemon.zenoh_session`.

A peer listening on an ephemeral loopback port and connecting to the daemon's (or router's)
conventional port, multicast scouting off, gossip on; ``--connect-timeout`` makes the command
fail when nothing is reached. Import this module only where Zenoh is needed (``roger record``,
``roger replay --publish``).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from roger_daemon.zenoh_session import (
    DAEMON_ENDPOINT,
    ZenohSettings,
    add_zenoh_args,
    endpoints,
    settings_from_args,
    wait_connected,
    zenoh_config,
)

if TYPE_CHECKING:
    import zenoh

__all__ = [
    "DEFAULT_CONNECT",
    "DEFAULT_LISTEN",
    "add_arguments",
    "connect_endpoints",
    "make_config",
    "reached",
]

#: The conventional port of the daemon or router on this machine.
DEFAULT_CONNECT = (DAEMON_ENDPOINT,)
#: An ephemeral loopback port (others find it by gossip).
DEFAULT_LISTEN = ("tcp/127.0.0.1:0",)


def make_config(
    *,
    listen: Sequence[str] = DEFAULT_LISTEN,
    connect: Sequence[str] = DEFAULT_CONNECT,
    mode: str = "peer",
    config_file: str | None = None,
) -> zenoh.Config:
    """A Zenoh config: ``config_file`` (JSON5) if given, then mode/endpoints/scouting on top."""
    return zenoh_config(ZenohSettings(
        config_file=Path(config_file) if config_file else None, mode=mode,
        listen=endpoints(listen), connect=endpoints(connect), multicast_scouting=False,
        gossip=True))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The Zenoh flags with the recorder's defaults, and ``--connect-timeout``."""
    add_zenoh_args(parser, listen=DEFAULT_LISTEN, connect=DEFAULT_CONNECT, gossip=True,
                   connect_help="Zenoh endpoint to connect to")
    parser.add_argument("--connect-timeout", type=float, default=5.0, metavar="S",
                        help="exit 1 if no --connect endpoint is reached within S seconds "
                             "(default 5; 0: go on anyway, waiting for others to connect)")


def reached(session: zenoh.Session, args: argparse.Namespace, command: str) -> bool:
    """True once ``session`` is connected to a peer or router (or nothing is to be reached);
    else False after ``--connect-timeout`` seconds, with a message on stderr.

    A peer whose ``--connect`` endpoint is down still opens (and retries in the background),
    so without this check a tool would silently record or publish nothing.
    """
    wanted = connect_endpoints(args)
    if not wanted or args.connect_timeout <= 0 or wait_connected(session, args.connect_timeout):
        return True
    print(f"{command}: cannot reach {', '.join(wanted)} within {args.connect_timeout:g} s "
          "(is the daemon or router running there?); nothing done. Use --connect-timeout 0 "
          "to go on anyway", file=sys.stderr, flush=True)
    return False


def connect_endpoints(args: argparse.Namespace) -> list[str]:
    """The ``--connect`` endpoints of parsed :func:`add_arguments` options (default applied)."""
    return list(settings_from_args(args).connect or ())
