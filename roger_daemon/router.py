"""``roger router``: a Zenoh router as a Python session in router mode.

For several hosts: run one router, and start daemons, simulators and controllers as Zenoh
clients that ``connect`` to it; nothing else changes. The default config listens on loopback
only; a router that listens where other hosts reach it without authentication or without an
``access_control`` block is warned about, and the shipped example passwords are refused
unless ``--insecure-example``. The secure deployment (user/password authentication and an
ACL by role) is ``configs/zenoh/secure/`` (``docs/security.md``). Stops cleanly on SIGTERM/SIGINT.
"""

from __future__ import annotations

import argparse
import json
import logging
import signal
import time
from pathlib import Path
from types import FrameType
from typing import Any

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
    parser.add_argument("--insecure-example", action="store_true",
                        help="start even though the credentials are the shipped example's "
                             "(passwords change-me-*): for a try on one machine only")


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


#: the passwords of the shipped example credentials (configs/zenoh/secure/), never to be used
EXAMPLE_PASSWORD_PREFIX = "change-me"


def example_credentials(dictionary_file: str | None) -> list[str]:
    """The users of ``dictionary_file`` (``user:password`` lines) whose password is one of the
    shipped example's (``change-me-*``, docs/security.md); [] if none or unreadable (Zenoh
    reports an unreadable file itself)."""
    if not dictionary_file:
        return []
    try:
        lines = Path(dictionary_file).read_text().splitlines()
    except (OSError, UnicodeDecodeError):
        return []
    return [user for user, _, pw in (ln.strip().partition(":") for ln in lines)
            if pw.startswith(EXAMPLE_PASSWORD_PREFIX)]


def exposure_warning(listen: list[str], *, acl: bool, auth: bool) -> str:
    """What a router listening on ``listen`` must be warned about ("" if nothing): a listener
    other hosts reach without authentication (anyone there connects) or without an ACL (any
    client may publish anything); docs/security.md."""
    public = exposed(listen)
    missing = [what for what, ok in (("authentication", auth), ("access control", acl))
               if not ok]
    if not public or not missing:
        return ""
    return (f"the router listens on {', '.join(public)}, reachable from other hosts, WITHOUT "
            f"{' or '.join(missing)}: anyone there can connect"
            + (" as any role" if acl else "") + " and publish control (reset) or impersonate "
            "a daemon. Use configs/zenoh/secure/router.json5 (docs/security.md)")


def _authenticated(cfg: Any) -> bool:
    """Whether the router's config makes a client prove who it is (user/password or mTLS)."""
    usrpwd = json.loads(cfg.get_json("transport/auth/usrpwd/dictionary_file"))
    mtls = json.loads(cfg.get_json("transport/link/tls/enable_mtls"))
    return bool(usrpwd) or bool(mtls)


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
    dictionary = json.loads(cfg.get_json("transport/auth/usrpwd/dictionary_file"))
    if (users := example_credentials(dictionary)) and not args.insecure_example:
        log.error("%s holds the shipped example passwords (change-me-*) for %s: anyone who "
                  "read the example can connect. Write your own dictionary (chmod 600) and "
                  "pass --set 'transport/auth/usrpwd/dictionary_file=\"PATH\"', or "
                  "--insecure-example to try it on one machine (docs/security.md)",
                  dictionary, ", ".join(users))
        return 2
    if users:
        log.warning("running with the example passwords of %s (--insecure-example)", dictionary)
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
        if warning := exposure_warning(listen, acl=bool(acl), auth=_authenticated(cfg)):
            log.warning("%s", warning)
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
