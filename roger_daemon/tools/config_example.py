"""``roger config example NAME``: print a configuration file shipped with the package.

The files are the repository's ``configs/`` (the one copy; the package reaches them through
``roger_daemon/configs``, a symlink that the wheel turns into package data), so an installed
``roger`` prints the same text the repository holds. Redirect to start your own::

    roger config example daemon > my-daemon.toml
    roger config example systemd > ~/.config/systemd/user/roger-daemon.service
"""

from __future__ import annotations

import argparse
import sys
from importlib import resources

from roger_daemon.console import UsageError

#: NAME -> file under configs/, and what it is
EXAMPLES: dict[str, tuple[str, str]] = {
    "daemon": ("roger.toml", "the daemon's TOML config (every key, defaults, comments)"),
    "task": ("aibo.toml", "the AIBO task of the simulator and controller"),
    "router": ("zenoh/router.json5", "a Zenoh router (roger router --config)"),
    "router-acl": ("zenoh/router-acl.json5", "a Zenoh router with access control"),
    "peer": ("zenoh/peer-loopback.json5", "a Zenoh peer on loopback only"),
    "client": ("zenoh/client.json5", "a Zenoh client of a router"),
    "systemd": ("systemd/roger-daemon.service", "a systemd unit for roger daemon"),
    "systemd-router": ("systemd/roger-router.service", "a systemd unit for roger router"),
    "up": ("up-demonstration.toml", "a launch file for roger up (a demonstration session)"),
    "up-play": ("up-play.toml", "a launch file for roger up: the robot plays alone (roger play)"),
    "held-out-poses": ("held-out-poses.toml",
                       "start poses the demonstrations never used (experiment --start-poses)"),
    "robot-aibo": ("robots/aibo.toml", "a robot profile: the AIBO's names and ranges "
                                       "([[robots]] profile; copy it for your own robot)"),
    "secure-router": ("zenoh/secure/router.json5",
                      "a router with user/password authentication and an ACL by role"),
    "secure-daemon": ("zenoh/secure/daemon.json5", "the daemon as an authenticated client"),
    "secure-daemon-toml": ("zenoh/secure/daemon.toml",
                           "the daemon's TOML config for the secure router"),
    "secure-robot": ("zenoh/secure/robot.json5", "a robot as an authenticated client"),
    "secure-operator": ("zenoh/secure/operator.json5",
                        "an operator tool (status, control) as an authenticated client"),
    "secure-credentials": ("zenoh/secure/credentials.example.txt",
                           "the router's credentials file (example; set your own passwords)"),
}


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roger config``."""
    sub = parser.add_subparsers(dest="config_command", metavar="ACTION")
    sub.required = True
    p = sub.add_parser("example", help="print a shipped config file to stdout")
    p.add_argument("name", metavar="NAME", help="one of: " + ", ".join(
        f"{k} ({v[1]})" for k, v in EXAMPLES.items()))
    sub.add_parser("list", help="the names of the shipped config files and where they are")


def text_of(name: str) -> str:
    """The text of the shipped file called ``name``."""
    if name not in EXAMPLES:
        raise UsageError(f"config example NAME must be one of {', '.join(EXAMPLES)}, "
                         f"got {name!r}")
    return (resources.files("roger_daemon") / "configs" / EXAMPLES[name][0]).read_text(
        encoding="utf-8")


def run(args: argparse.Namespace) -> int:
    """Print one file, or the list."""
    if args.config_command == "list":
        base = resources.files("roger_daemon") / "configs"
        for name, (rel, what) in EXAMPLES.items():
            print(f"{name:15s} {what}\n{'':15s} {base / rel}")
        return 0
    sys.stdout.write(text_of(args.name))
    sys.stdout.flush()
    return 0
