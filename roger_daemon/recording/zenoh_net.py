"""Zenoh session config for the recorder and the replay publisher (loopback peers).

Peer mode, multicast scouting off, gossip on, explicit endpoints on 127.0.0.1 by default.
Import this module only where Zenoh is needed (``roger record``, ``roger replay --publish``).
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence

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
DEFAULT_CONNECT = ("tcp/127.0.0.1:7447",)
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
    cfg = zenoh.Config.from_file(config_file) if config_file else zenoh.Config()
    cfg.insert_json5("mode", json.dumps(mode))
    cfg.insert_json5("listen/endpoints", json.dumps(_endpoints(listen)))
    cfg.insert_json5("connect/endpoints", json.dumps(_endpoints(connect)))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    cfg.insert_json5("scouting/gossip/enabled", "true")
    return cfg


def _endpoints(eps: Sequence[str]) -> list[str]:
    """Endpoints, where the single word ``none`` means no endpoint."""
    return [e for e in eps if e.strip().lower() != "none"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``--connect``, ``--listen`` (repeatable) and ``--zenoh-config``."""
    parser.add_argument(
        "--connect",
        action="append",
        metavar="ENDPOINT",
        help=f"Zenoh endpoint to connect to (repeatable; 'none' for none; default "
        f"{DEFAULT_CONNECT[0]})",
    )
    parser.add_argument(
        "--listen",
        action="append",
        metavar="ENDPOINT",
        help=f"Zenoh endpoint to listen on (repeatable; 'none' for none; default "
        f"{DEFAULT_LISTEN[0]})",
    )
    parser.add_argument("--zenoh-config", metavar="FILE", help="Zenoh JSON5 config to start from")
    parser.add_argument("--connect-timeout", type=float, default=5.0, metavar="S",
                        help="exit 1 if no --connect endpoint is reached within S seconds "
                             "(default 5; 0: go on anyway, waiting for others to connect)")


def reached(session: zenoh.Session, args: argparse.Namespace, command: str) -> bool:
    """True once ``session`` is connected to a peer or router (or nothing is to be reached);
    else False after ``--connect-timeout`` seconds, with a message on stderr.

    A peer whose ``--connect`` endpoint is down still opens (and retries in the background),
    so without this check a tool would silently record or publish nothing.
    """
    import sys
    import time

    wanted = connect_endpoints(args)
    if not wanted or args.connect_timeout <= 0:
        return True
    end = time.monotonic() + args.connect_timeout
    while time.monotonic() < end:
        if list(session.info.peers_zid()) or list(session.info.routers_zid()):
            return True
        time.sleep(0.05)
    print(f"{command}: cannot reach {', '.join(wanted)} within {args.connect_timeout:g} s "
          "(is the daemon or router running there?); nothing done. Use --connect-timeout 0 "
          "to go on anyway", file=sys.stderr, flush=True)
    return False


def connect_endpoints(args: argparse.Namespace) -> list[str]:
    """The ``--connect`` endpoints of parsed :func:`add_arguments` options (default applied)."""
    return _endpoints(args.connect if args.connect is not None else DEFAULT_CONNECT)


def config_from_args(args: argparse.Namespace) -> zenoh.Config:
    """The config for parsed :func:`add_arguments` options."""
    return make_config(
        listen=args.listen if args.listen is not None else DEFAULT_LISTEN,
        connect=args.connect if args.connect is not None else DEFAULT_CONNECT,
        config_file=args.zenoh_config,
    )
