"""The ``roger`` command: one entry point, one subcommand per process or tool.

Each subcommand lives in its own module that exposes two functions::

    def configure(parser: argparse.ArgumentParser) -> None: ...  # add arguments
    def run(args: argparse.Namespace) -> int: ...                # do the work, return exit code

Modules are imported lazily, only for the subcommand that runs, so ``roger bench learner``
never imports Zenoh or pybullet. Add a subcommand by adding one row to ``COMMANDS`` (or to
``BENCHES`` for ``roger bench NAME``).
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from collections.abc import Sequence

# name -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "bench": ("roger_daemon.bench", "benchmarks: learner, daemon, sim (table or --json)"),
    "daemon": ("roger_daemon.daemon", "the learner daemon: predictions, status, checkpoints"),
    "router": ("roger_daemon.router", "a Zenoh router (Python session) for several hosts"),
    "record": ("roger_daemon.recording.cli_record", "record Zenoh traffic to MCAP"),
    "log": ("roger_daemon.recording.cli_log", "log tools: info, recover, export"),
    "replay": ("roger_daemon.recording.cli_replay", "replay a log into the learner"),
    "sim": ("simulator.sim_node", "the AIBO soccer simulator (pybullet) as a Zenoh process"),
    "hcc": ("simulator.hcc_node", "the hand-coded FSM goal scorer: demonstrator or transitioner"),
    "experiment": ("simulator.experiment.cli", "experiments: goal-scoring (paper section IV)"),
    "demo": ("simulator.experiment.demo", "a short end-to-end session: demonstrate, learn, act"),
}

# roger bench NAME -> (module, one-line help); each module has configure() and run()
BENCHES: dict[str, tuple[str, str]] = {
    "learner": ("roger_daemon.bench.learner", "learner updates/s and latency, synthetic stream"),
    "recorder": ("roger_daemon.recording.bench", "recorder write+poll cost, SIGKILL loss"),
    "daemon": ("roger_daemon.bench.daemon", "daemon end to end: latency, 30 Hz jitter, updates/s"),
    "fleet": ("roger_daemon.bench.fleet", "N robots x 30 Hz against one daemon, per robot"),
    "soak": ("roger_daemon.bench.soak", "daemon RSS over a 30 Hz run, checkpoint bytes/expert"),
    "sim": ("simulator.bench", "simulator lockstep ticks/s (rendered, fast) and HCC success"),
}


def _configure_logging() -> None:
    """Log once, to stderr, in a journald-friendly format (no timestamps under systemd)."""
    level = os.environ.get("ROGER_LOG_LEVEL", "INFO").upper()
    under_journal = "JOURNAL_STREAM" in os.environ or "INVOCATION_ID" in os.environ
    fmt = "%(levelname)s %(name)s: %(message)s" if under_journal else (
        "%(asctime)s %(levelname)s %(name)s: %(message)s"
    )
    logging.basicConfig(level=level, format=fmt, stream=sys.stderr)


def dispatch(table: dict[str, tuple[str, str]], prog: str, argv: Sequence[str]) -> int:
    """Parse ``argv`` against ``table`` and run the chosen module."""
    parser = argparse.ArgumentParser(prog=prog)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    wanted = next((a for a in argv if not a.startswith("-")), None)
    for name, (module, help_text) in table.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        if name == wanted:
            importlib.import_module(module).configure(p)
        p.set_defaults(_module=module)
    args = parser.parse_args(list(argv))
    from roger_daemon.blas import pin_blas_threads

    pin_blas_threads(1)  # results never depend on the BLAS thread count (roger_daemon/blas.py)
    code: int = importlib.import_module(args._module).run(args)
    return code


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``roger`` console script."""
    _configure_logging()
    return dispatch(COMMANDS, "roger", sys.argv[1:] if argv is None else list(argv))
