"""The one owner of Zenoh session setup: settings, command-line flags, config, session.

Every ROGER process (daemon, operator tools, recorder, replay, simulator, controllers) joins
Zenoh through this module, with one layering, as zenoh-python's own examples do
(``conf = zenoh.Config.from_file(path)`` if a file is given, then ``conf.insert_json5(...)`` for
each flag, then ``with zenoh.open(conf) as session:``):

1. the JSON5 file (``--zenoh-config FILE``, ``[zenoh] config_file``), else an empty config;
2. the settings (:class:`ZenohSettings`): every field that is not ``None`` is set on top:
   ``mode``, ``listen``/``connect`` endpoints, multicast scouting, gossip, lease;
3. overrides: raw ``KEY=JSON5`` pairs (``--zenoh-set``), applied last.

Without a file a command's defaults fill the settings (a peer on explicit loopback endpoints,
multicast scouting off); with a file only the flags given on the command line override it.
Endpoint flags are repeatable and take comma lists; the word ``none`` stands for no endpoint.

Zenoh is imported only when a config is built, so importing this module costs nothing.
:func:`open_session` leaves Zenoh on its own multi-thread runtimes (``ZENOH_RUNTIME`` in the
environment still decides): on one thread, a router waiting inside a BLOCK sample for a busy
subscriber forwarded nothing else for 5 s (docs/zenoh-notes.md §1.3, issue 55).
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import zenoh

__all__ = [
    "DAEMON_ENDPOINT",
    "DAEMON_PORT",
    "ZenohOverrideError",
    "ZenohSettings",
    "add_zenoh_args",
    "endpoints",
    "open_session",
    "settings_from_args",
    "wait_connected",
    "zenoh_config",
]


class ZenohOverrideError(ValueError):
    """An override (``KEY=JSON5``) that Zenoh rejects: an unknown key or a bad value."""


REALTIME_QUEUE = 16  # Zenoh's maximum



#: The daemon's conventional port on this machine, and its default endpoint: where ``roger
#: daemon`` listens unless ``[zenoh] listen`` says otherwise, and where every client, tool and
#: simulator node connects by default (``configs/roger.toml``).
DAEMON_PORT = 7447
DAEMON_ENDPOINT = f"tcp/127.0.0.1:{DAEMON_PORT}"


@dataclass(frozen=True)
class ZenohSettings:
    """How a process joins Zenoh. ``None`` means "leave to the JSON5 file or Zenoh's default"."""

    config_file: Path | None = None
    mode: str | None = "peer"
    listen: tuple[str, ...] | None = (DAEMON_ENDPOINT,)
    connect: tuple[str, ...] | None = ()
    multicast_scouting: bool | None = False
    lease_ms: int | None = None
    gossip: bool | None = None
    #: ``(key, JSON5 value)`` pairs inserted last, e.g. ``("transport/link/tx/lease", "500")``
    overrides: tuple[tuple[str, str], ...] = ()
    #: batches of the real-time priority's send queue per link (Zenoh's default is 2, and a
    #: drop-on-congestion message waits 1 ms for one): 8 robots' predictions published in
    #: one burst on a busy CPU were dropped at 2 (docs/zenoh-notes.md §4.3)
    realtime_queue: int | None = REALTIME_QUEUE


def zenoh_config(settings: ZenohSettings) -> zenoh.Config:
    """A ``zenoh.Config``: the JSON5 file (if any), the settings on top, then the overrides."""
    import zenoh

    s = settings
    cfg = zenoh.Config.from_file(str(s.config_file)) if s.config_file else zenoh.Config()
    for key, value in (("mode", s.mode),
                       ("listen/endpoints", None if s.listen is None else list(s.listen)),
                       ("connect/endpoints", None if s.connect is None else list(s.connect)),
                       ("scouting/multicast/enabled", s.multicast_scouting),
                       ("scouting/gossip/enabled", s.gossip),
                       ("transport/link/tx/lease", s.lease_ms),
                       ("transport/link/tx/queue/size/real_time", s.realtime_queue)):
        if value is not None:
            cfg.insert_json5(key, json.dumps(value))
    for key, text in s.overrides:
        try:
            cfg.insert_json5(key, text)
        except Exception as exc:  # zenoh.ZError: unknown key or bad JSON5
            raise ZenohOverrideError(f"{key}={text}: {exc}") from None
    return cfg


def open_session(conf: ZenohSettings | zenoh.Config) -> zenoh.Session:
    """Open a ``zenoh.Session`` (call after any fork); use it as ``with open_session(s) as z:``
    or close it yourself.

    Zenoh's own multi-thread runtimes, unless the environment's ``ZENOH_RUNTIME`` says
    otherwise: not one worker for all, which a BLOCK sample stalls (docs/zenoh-notes.md §1.3)."""
    import zenoh

    return zenoh.open(zenoh_config(conf) if isinstance(conf, ZenohSettings) else conf)


def endpoints(values: Iterable[str]) -> tuple[str, ...]:
    """Endpoints from flag values: comma lists split, blanks and the word ``none`` dropped."""
    out: list[str] = []
    for value in values:
        out.extend(e.strip() for e in value.split(",")
                   if e.strip() and e.strip().lower() != "none")
    return tuple(out)


def add_zenoh_args(
    parser: argparse.ArgumentParser, *, listen: Sequence[str] = (),
    connect: Sequence[str] = (), lease_ms: int | None = None, gossip: bool | None = None,
    connect_help: str = "endpoint to connect to",
) -> None:
    """``--listen``, ``--connect`` (repeatable, comma lists, ``none``), ``--zenoh-config`` and
    ``--zenoh-set``; ``listen``/``connect``/``lease_ms``/``gossip`` are this command's
    defaults when no file is given (:func:`settings_from_args`)."""
    g = parser.add_argument_group("zenoh")
    g.add_argument("--listen", action="append", default=None, metavar="ENDPOINT",
                   help=f"endpoint to listen on, e.g. tcp/127.0.0.1:7450; repeatable; 'none' "
                        f"for none (default: {', '.join(listen) or 'none'})")
    g.add_argument("--connect", action="append", default=None, metavar="ENDPOINT",
                   help=f"{connect_help}; repeatable; 'none' for none (default: "
                        f"{', '.join(connect) or 'none'})")
    g.add_argument("--zenoh-config", type=Path, default=None, metavar="FILE",
                   help="a Zenoh JSON5 config file to start from (--listen and --connect "
                        "still override it)")
    g.add_argument("--zenoh-set", action="append", default=[], metavar="KEY=JSON5",
                   help="set one Zenoh config key last, e.g. transport/link/tx/lease=500; "
                        "repeatable")
    parser.set_defaults(_zenoh_defaults=ZenohSettings(
        mode="peer", listen=tuple(listen), connect=tuple(connect), multicast_scouting=False,
        lease_ms=lease_ms, gossip=gossip))


def settings_from_args(args: argparse.Namespace) -> ZenohSettings:
    """The settings parsed :func:`add_zenoh_args` flags ask for (file, flags, overrides).

    Raises ``roger_daemon.console.UsageError`` for a missing file or a malformed override.
    """
    from roger_daemon.console import UsageError

    base: ZenohSettings = args._zenoh_defaults
    if args.zenoh_config is not None:
        if not Path(args.zenoh_config).is_file():
            raise UsageError(f"--zenoh-config: no such file: {args.zenoh_config}")
        # with a file, only the flags given on the command line override it
        base = ZenohSettings(config_file=Path(args.zenoh_config), mode=None, listen=None,
                             connect=None, multicast_scouting=None, realtime_queue=None)
    if args.listen is not None:
        base = replace(base, listen=endpoints(args.listen))
    if args.connect is not None:
        base = replace(base, connect=endpoints(args.connect))
    overrides = []
    for item in args.zenoh_set:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise UsageError(f"--zenoh-set {item!r}: expected KEY=JSON5, e.g. "
                             "transport/link/tx/lease=500")
        overrides.append((key.strip(), value))
    return replace(base, overrides=tuple(overrides))


def wait_connected(session: zenoh.Session, timeout: float) -> bool:
    """Whether ``session`` reaches a peer or router within ``timeout`` seconds.

    A peer whose ``connect`` endpoint is down still opens (and retries in the background);
    this tells a tool that would otherwise silently send or receive nothing.
    """
    end = time.monotonic() + timeout
    while True:
        if list(session.info.peers_zid()) or list(session.info.routers_zid()):
            return True
        if time.monotonic() >= end:
            return False
        time.sleep(0.05)
