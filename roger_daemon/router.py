"""``roger router``: a Zenoh router as a Python session in router mode.

For several hosts: run one router, and start daemons, simulators and controllers as Zenoh
clients that ``connect`` to it; nothing else changes. The default config listens on loopback
only; a router that listens where other hosts reach it without an ``access_control`` block is
warned about. The secure deployment (user/password authentication and an ACL by role) is
``configs/zenoh/secure/`` (``docs/security.md``). Stops cleanly on SIGTERM/SIGINT.
"""

from __future__ import annotations

import argparse
import json
import logging
import signal
import time
from pathlib import Path
from types import FrameType

from roger_daemon.daemon.sdnotify import Notifier
from roger_daemon.zenoh_session import (
    ZenohOverrideError,
    ZenohSettings,
    open_session,
    zenoh_config,
)

__all__ = ["configure", "run"]

log = logging.getLogger(__name__)

DEFAULT_CONFIG = Path("configs/zenoh/router.json5")


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roger router``."""
    parser.add_argument("--config", type=Path, default=DEFAULT_CONFIG,
                        help=f"Zenoh JSON5 config (default {DEFAULT_CONFIG})")
    parser.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                        help="listen endpoint, replacing the file's (repeatable), "
                             "e.g. tcp/0.0.0.0:7447")
    parser.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                        help="another router to connect to (repeatable)")
    parser.add_argument("--set", dest="overrides", action="append", default=[],
                        metavar="KEY=JSON5",
                        help="override one Zenoh config key after the file and the flags, "
                             "e.g. transport/auth/usrpwd/dictionary_file='\"/etc/roger/creds\"'")


def exposed(listen: list[str]) -> list[str]:
    """The listen endpoints reachable from other hosts (not loopback, not a unix socket)."""
    out = []
    for ep in listen:
        proto, _, addr = ep.partition("/")
        if proto.startswith("unix"):
            continue
        host = addr.rsplit(":", 1)[0].strip("[]").lower()
        if not (host == "localhost" or host == "::1" or host.startswith("127.")):
            out.append(ep)
    return out


def run(args: argparse.Namespace) -> int:
    """Run the router until SIGTERM/SIGINT."""

    stop = {"flag": False}

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        log.info("received %s", signal.Signals(signum).name)
        stop["flag"] = True

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    overrides = []
    for item in args.overrides:
        key, sep, value = item.partition("=")
        if not sep:
            log.error("--set %r: must be KEY=JSON5 with a Zenoh config key, e.g. "
                      "listen/endpoints='[\"tcp/127.0.0.1:7447\"]' (expected KEY=JSON5)", item)
            return 2
        overrides.append((key.strip(), value))
    # the file, then router mode and the endpoint flags, then the overrides
    settings = ZenohSettings(config_file=args.config, mode="router",
                             listen=tuple(args.listen) or None,
                             connect=tuple(args.connect) or None, multicast_scouting=None,
                             overrides=tuple(overrides))
    try:
        cfg = zenoh_config(settings)
    except ZenohOverrideError as exc:
        log.error("--set: must be KEY=JSON5 with a Zenoh config key, e.g. "
                  "listen/endpoints='[\"tcp/127.0.0.1:7447\"]' (%s)", exc)
        return 2
    except Exception as exc:  # ZError: unreadable or invalid JSON5
        log.error("config error: %s is not a usable Zenoh config: %s", args.config, exc)
        return 2
    try:
        session = open_session(cfg)
    except Exception as exc:
        log.error("cannot start the router: %s", exc)
        return 1
    notifier = Notifier.from_env()
    try:
        listen = json.loads(cfg.get_json("listen/endpoints"))
        acl = json.loads(cfg.get_json("access_control/enabled"))
        log.info("router %s listening on %s (access control %s)", session.zid(), listen,
                 "on" if acl else "off")
        if exposed(listen) and not acl:
            log.warning("the router listens on %s, reachable from other hosts, WITHOUT access "
                        "control: anyone there can publish control (reset) or impersonate a "
                        "daemon. Use configs/zenoh/secure/router.json5 (docs/security.md)",
                        ", ".join(exposed(listen)))
        notifier.ready(f"router listening on {listen}")
        while not stop["flag"]:
            time.sleep(0.1)
            notifier.watchdog(time.monotonic_ns())
        notifier.stopping()
    finally:
        session.close()
        notifier.close()
    log.info("router stopped")
    return 0
