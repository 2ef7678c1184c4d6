"""What the operator tools share: connecting, listening, decoding, printing.

- :func:`add_connection_args` / :func:`settings_from_args`: the Zenoh flags of every process
  (:mod:`roger_daemon.zenoh_session`: ``--connect``, ``--listen``, ``--zenoh-config``,
  ``--zenoh-set``) and ``--timeout``;
- :class:`Listener`: a subscriber whose callback only copies the sample onto a bounded queue
  (nothing of ours runs long on Zenoh's threads); the command's thread takes from it;
- :func:`decode_sample`: a key ``roger/<robot>/<kind>`` and its payload as a plain map;
- :func:`key_expr`: a user's KEY argument as a key expression (``aibo/status`` is short for
  ``roger/aibo/status``), rejected with exit status 2 when it is not one.
"""

from __future__ import annotations

import argparse
import json
import math
import queue
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

from protocols import decode, keys
from protocols.errors import ProtocolError
from roger_daemon.console import UsageError
from roger_daemon.zenoh_session import DAEMON_ENDPOINT, add_zenoh_args, settings_from_args

__all__ = [
    "DEFAULT_CONNECT",
    "Listener",
    "Sample",
    "UsageError",
    "add_connection_args",
    "count",
    "port",
    "seconds",
    "decode_sample",
    "dumps",
    "key_expr",
    "non_negative",
    "open_from_args",
    "settings_from_args",
]

DEFAULT_CONNECT = DAEMON_ENDPOINT  # the daemon's default listen endpoint


def count(text: str) -> int:
    """argparse type: an integer >= 0 (argparse reports a bad one and exits 2)."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}")
    return value


def seconds(text: str) -> float:
    """argparse type: a finite number of seconds >= 0."""
    return _finite_non_negative(text, "a number of seconds >= 0")


def non_negative(text: str) -> float:
    """argparse type: a finite number >= 0.

    >>> non_negative("2.5"), non_negative("0")
    (2.5, 0.0)
    """
    return _finite_non_negative(text, "a finite number >= 0")


def _finite_non_negative(text: str, expected: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not math.isfinite(value) or value < 0:
        raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
    return value


def port(text: str) -> int:
    """argparse type: a TCP port, 0 (any free one) to 65535."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= 65535:
        raise argparse.ArgumentTypeError(f"expected a port 0-65535, got {text!r}")
    return value


def add_connection_args(parser: argparse.ArgumentParser, *, timeout: float = 5.0) -> None:
    """The Zenoh flags (:func:`~roger_daemon.zenoh_session.add_zenoh_args`: a peer that listens
    nowhere and connects to the daemon by default) and ``--timeout``."""
    add_zenoh_args(parser, listen=(), connect=(DEFAULT_CONNECT,),
                   connect_help="endpoint of the daemon (or router) to connect to")
    parser.add_argument("--timeout", type=seconds, default=timeout, metavar="S",
                        help=f"give up after this many seconds without an answer "
                             f"(default: {timeout:g})")


def open_from_args(args: argparse.Namespace) -> Any:
    """The Zenoh session the command line asked for (``UsageError`` if it cannot open)."""
    from roger_daemon.zenoh_session import open_session

    settings = settings_from_args(args)
    try:
        return open_session(settings)
    except Exception as exc:  # zenoh.ZError for a malformed endpoint or config
        raise UsageError(f"cannot open a Zenoh session with {settings.connect or '(file)'}: "
                         f"{exc}") from None


def key_expr(text: str) -> str:
    """``KEY`` as a key expression under ``roger/`` (``aibo/status`` -> ``roger/aibo/status``)."""
    import zenoh

    full = text if text.startswith(keys.ROOT + "/") or text == keys.ROOT else (
        f"{keys.ROOT}/{text}")
    try:
        zenoh.KeyExpr(full)
    except Exception:
        raise UsageError(
            f"KEY must be a key expression such as roger/aibo/status, aibo/prediction or "
            f"roger/*/status, got {text!r}") from None
    return full


@dataclass(frozen=True, slots=True)
class Sample:
    """One received sample: key, bytes, and ``time.monotonic()`` at receipt."""

    key: str
    payload: bytes
    recv_s: float


class Listener:
    """A subscriber on ``key_expr`` feeding a bounded queue; overflow is counted."""

    def __init__(self, session: Any, key_expr: str, capacity: int = 4096,
                 *, liveliness: bool = False, history: bool = False) -> None:
        self._q: queue.Queue[Sample] = queue.Queue(maxsize=capacity)
        self._lock = threading.Lock()
        self.overflow = 0

        def on_sample(sample: Any) -> None:
            item = Sample(str(sample.key_expr), sample.payload.to_bytes(), time.monotonic())
            try:
                self._q.put_nowait(item)
            except queue.Full:
                with self._lock:
                    self.overflow += 1

        if liveliness:  # history: the tokens alive now are delivered at once
            self._sub = session.liveliness().declare_subscriber(key_expr, on_sample,
                                                                history=history)
        else:
            self._sub = session.declare_subscriber(key_expr, on_sample)

    def get(self, timeout: float) -> Sample | None:
        """The next sample, or ``None`` after ``timeout`` seconds."""
        try:
            return self._q.get(timeout=max(timeout, 0.0)) if timeout > 0 else (
                self._q.get_nowait())
        except queue.Empty:
            return None

    def decoded(self, deadline: float,
                on_invalid: Callable[[Sample, ProtocolError], None] | None = None,
                ) -> Iterator[dict[str, Any]]:
        """Decoded messages (:func:`decode_sample`) as they arrive, until the monotonic
        ``deadline``; an invalid one is skipped (and passed to ``on_invalid``, if given)."""
        while (left := deadline - time.monotonic()) > 0:
            s = self.get(min(left, 0.2))
            if s is None:
                continue
            try:
                yield decode_sample(s.key, s.payload)
            except ProtocolError as exc:
                if on_invalid is not None:
                    on_invalid(s, exc)

    def close(self) -> None:
        """Undeclare the subscriber."""
        try:
            self._sub.undeclare()
        except Exception:  # already gone with the session
            pass


def decode_sample(key: str, payload: bytes) -> dict[str, Any]:
    """The message on ``key`` as a plain map; ``ProtocolError`` if it is not a valid one."""
    robot, kind = keys.parse(key)
    return decode(kind, payload, robot=robot).to_map()


def _rounded(value: Any, digits: int) -> Any:
    if isinstance(value, float):
        return round(value, digits)
    if isinstance(value, list):
        return [_rounded(v, digits) for v in value]
    if isinstance(value, dict):
        return {k: _rounded(v, digits) for k, v in value.items()}
    return value


def dumps(obj: Any, *, digits: int | None = None) -> str:
    """One JSON line (``digits``: round floats for reading)."""
    return json.dumps(obj if digits is None else _rounded(obj, digits), separators=(",", ":"))


def invalid_text(key: str, exc: ProtocolError) -> str:
    """How a tool reports a sample that does not decode."""
    return f"{key}: invalid message ({exc.reason}: {exc.detail})"
