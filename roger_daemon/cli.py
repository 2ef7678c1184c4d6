"""The ``roger`` command: one entry point, one subcommand per process or tool.

Each subcommand lives in its own module that exposes two functions::

    def configure(parser: argparse.ArgumentParser) -> None: ...  # add arguments
    def run(args: argparse.Namespace) -> int: ...                # do the work, return exit code

Modules are imported lazily, only for the subcommand that runs, so ``roger bench learner``
never imports Zenoh or pybullet. Add a subcommand by adding one row to ``COMMANDS`` (or to
``BENCHES`` for ``roger bench NAME``).

Other installed packages add their own rows through the ``roger.commands`` entry point group:
each entry names a module with ``COMMANDS`` and ``BENCHES`` tables of the same form (the
simulator's is ``simulator.commands``). So this package never names the packages built on it:
``roger sim`` works where the simulator is installed, and the daemon does not depend on it.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Iterator, Mapping, Sequence
from importlib.metadata import entry_points

from roger_daemon import __version__
from roger_daemon.console import LOG_LEVELS, configure_logging, guarded

#: The entry point group of the packages that add subcommands.
ENTRY_POINT_GROUP = "roger.commands"


class CommandTable(Mapping[str, tuple[str, str]]):
    """``name -> (module, one-line help)``: this package's rows, then the ``attr`` table of
    every module registered under :data:`ENTRY_POINT_GROUP` (read on first use)."""

    def __init__(self, own: dict[str, tuple[str, str]], attr: str) -> None:
        self._own = own
        self._attr = attr
        self._rows: dict[str, tuple[str, str]] | None = None

    def _all(self) -> dict[str, tuple[str, str]]:
        if self._rows is None:
            rows = dict(self._own)
            for ep in sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda e: e.name):
                rows.update(getattr(ep.load(), self._attr, {}))
            self._rows = rows
        return self._rows

    def __getitem__(self, name: str) -> tuple[str, str]:
        return self._all()[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._all())

    def __len__(self) -> int:
        return len(self._all())


# name -> (module, one-line help)
COMMANDS = CommandTable({
    "bench": ("roger_daemon.bench", "benchmarks: learner, daemon, sim (table or --json)"),
    "daemon": ("roger_daemon.daemon.main", "the learner daemon: predictions, status, checkpoints"),
    "router": ("roger_daemon.router", "a Zenoh router (Python session) for several hosts"),
    "record": ("roger_daemon.recording.cli_record", "record Zenoh traffic to MCAP"),
    "log": ("roger_daemon.recording.cli_log", "log tools: info, recover, export"),
    "replay": ("roger_daemon.replay.cli", "replay a log into the learner"),
    "list": ("roger_daemon.tools.listing", "daemons alive (liveliness) and the robots they serve"),
    "status": ("roger_daemon.tools.status", "a robot's daemon status, readable (--watch, --json)"),
    "echo": ("roger_daemon.tools.echo", "print the decoded messages on a key expression"),
    "hz": ("roger_daemon.tools.hz", "the rate of messages on a key expression"),
    "control": ("roger_daemon.tools.control", "mode, reset or checkpoint, confirmed by the daemon"),
    "config": ("roger_daemon.tools.config_example", "print shipped config files (daemon, systemd)"),
    "model": ("roger_daemon.fsm.cli",
              "inspect a model: fsm (the learned transitions of a roger+fsm checkpoint)"),
    "compile": ("roger_daemon.tools.compile_kernels",
                "compile the learner's kernels into numba's cache, on every core"),
}, "COMMANDS")

# roger bench NAME -> (module, one-line help); each module has configure() and run()
BENCHES = CommandTable({
    "learner": ("roger_daemon.bench.learner",
                "learner updates/s and latency (synthetic or AIBO stream; --compare REF)"),
    "recorder": ("roger_daemon.bench.recorder", "recorder write+poll cost, SIGKILL loss"),
    "daemon": ("roger_daemon.bench.daemon", "daemon end to end: latency, 30 Hz jitter, updates/s"),
    "fleet": ("roger_daemon.bench.fleet", "N robots x 30 Hz against one daemon, per robot"),
    "soak": ("roger_daemon.bench.soak", "daemon RSS over a 30 Hz run, checkpoint bytes/expert"),
    "worker": ("roger_daemon.bench.worker",
               "one learner worker's CPU per robot and tick (learn, labels, predict)"),
}, "BENCHES")


def _add_log_level(parser: argparse.ArgumentParser, default: str | None) -> None:
    """``--log-level``, accepted before and after the subcommand (one name everywhere)."""
    parser.add_argument("--log-level", choices=LOG_LEVELS, type=str.lower,
                        default=default if default is not None else argparse.SUPPRESS,
                        help="log messages at this level and above on stderr (default: "
                             "$ROGER_LOG_LEVEL or info)")


def build_parser(table: Mapping[str, tuple[str, str]], prog: str,
                 wanted: str | None = None) -> argparse.ArgumentParser:
    """The parser of ``table``; only the ``wanted`` subcommand is configured (``"*"``: all)."""
    parser = argparse.ArgumentParser(prog=prog)
    if table is COMMANDS:
        parser.add_argument("--version", action="version", version=f"roger {__version__}",
                            help="print the version and exit")
        _add_log_level(parser, None)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name, (module, help_text) in table.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        if name == wanted or wanted == "*":
            importlib.import_module(module).configure(p)
            _add_log_level(p, None)
        p.set_defaults(_module=module)
    return parser


def dispatch(table: Mapping[str, tuple[str, str]], prog: str, argv: Sequence[str]) -> int:
    """Parse ``argv`` against ``table`` and run the chosen module."""
    wanted = next((a for a in argv if a in table), None)
    args = build_parser(table, prog, wanted).parse_args(list(argv))
    if table is COMMANDS or getattr(args, "log_level", None):  # bench NAME --log-level too
        configure_logging(getattr(args, "log_level", None))
    from roger_daemon.blas import pin_blas_threads

    pin_blas_threads(1)  # results never depend on the BLAS thread count (roger_daemon/blas.py)
    code: int = importlib.import_module(args._module).run(args)
    return code


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``roger`` console script."""
    args = sys.argv[1:] if argv is None else list(argv)
    return guarded("roger", lambda: dispatch(COMMANDS, "roger", args))
