"""How every ``roger`` command talks to the terminal: logging, user errors, Ctrl-C, broken pipes.

- :func:`configure_logging`: one stderr handler; ``--log-level`` (or ``ROGER_LOG_LEVEL``) sets
  the level; under systemd (``JOURNAL_STREAM`` or ``INVOCATION_ID`` set) no timestamps and each
  line starts with its syslog priority ``<N>`` (``<3>`` error, ``<4>`` warning, ``<6>`` info,
  ``<7>`` debug) so that ``journalctl -p warning`` filters (sd-daemon(3), SyslogLevelPrefix=).
- :class:`UsageError`: a bad value on the command line; :func:`guarded` prints
  ``roger CMD: message`` and returns 2, never a traceback.
- Ctrl-C (``KeyboardInterrupt``) returns 130 without a traceback; a closed stdout
  (``roger replay ... --json | head``) returns 141 quietly, as a process killed by SIGPIPE.
"""

from __future__ import annotations

import logging
import os
import signal
import sys
from collections.abc import Callable

__all__ = [
    "LOG_LEVELS",
    "JournalFormatter",
    "UsageError",
    "configure_logging",
    "exit_on_sigterm",
    "guarded",
    "require",
]

LOG_LEVELS = ("debug", "info", "warning", "error")
_PRIORITY = {logging.DEBUG: 7, logging.INFO: 6, logging.WARNING: 4, logging.ERROR: 3,
             logging.CRITICAL: 2}


class UsageError(Exception):
    """A bad command-line value; the message names what is wrong, the expected form and the
    value given."""


def require(ok: bool, option: str, form: str, value: object) -> None:
    """Raise :class:`UsageError` (``OPTION must be FORM, got VALUE``) unless ``ok``."""
    if not ok:
        raise UsageError(f"{option} must be {form}, got {value!r}")


class JournalFormatter(logging.Formatter):
    """``<N>LEVEL name: message`` with N the syslog priority of the record's level."""

    def format(self, record: logging.LogRecord) -> str:
        """The record's text, every line prefixed with its syslog priority ``<N>``."""
        prio = _PRIORITY.get(record.levelno, 6 if record.levelno < logging.WARNING else 3)
        text = super().format(record)
        # every line of a multi-line message (tracebacks) keeps the priority
        return "\n".join(f"<{prio}>{line}" for line in text.splitlines() or [""])


def under_journal() -> bool:
    """Whether stderr goes to systemd's journal."""
    return "JOURNAL_STREAM" in os.environ or "INVOCATION_ID" in os.environ


def configure_logging(level: str | None = None) -> None:
    """Log to stderr at ``level`` (default: ``ROGER_LOG_LEVEL`` or INFO); journald-aware."""
    name = (level or os.environ.get("ROGER_LOG_LEVEL") or "INFO").upper()
    if logging.getLevelName(name) not in _PRIORITY:
        raise UsageError(f"log level must be one of {', '.join(LOG_LEVELS)}, got {name!r}")
    handler = logging.StreamHandler(sys.stderr)
    if under_journal():
        handler.setFormatter(JournalFormatter("%(levelname)s %(name)s: %(message)s"))
    else:
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger()
    for old in list(root.handlers):
        if getattr(old, "_roger", False):
            root.removeHandler(old)
    handler._roger = True  # type: ignore[attr-defined]
    root.addHandler(handler)
    root.setLevel(name)


def guarded(prog: str, body: Callable[[], int]) -> int:
    """Run ``body`` and turn user errors, Ctrl-C and a closed stdout into exit statuses."""
    try:
        code = body()
        sys.stdout.flush()  # a closed pipe shows here, not in the interpreter's final flush
        return code
    except UsageError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        _silence_stdout()
        return 141


def exit_on_sigterm() -> None:
    """SIGTERM raises ``SystemExit(143)`` in the main thread, so that ``finally`` blocks run
    and stop the processes a command started (the default action would end this one at once
    and leave them running). For commands without a SIGTERM handler of their own."""

    def _exit(signum: int, frame: object) -> None:
        sys.exit(128 + signum)

    signal.signal(signal.SIGTERM, _exit)


def _silence_stdout() -> None:
    """After EPIPE: point stdout at /dev/null so the interpreter's final flush is quiet."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):  # no real stdout (captured in tests)
        pass
