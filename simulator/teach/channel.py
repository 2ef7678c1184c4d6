"""The page's input channel: what a teacher's page (or the scripted teacher) may send, checked.

Every message from a page is one JSON object (a WebSocket text frame) with a ``type``:

* ``command``: the teacher's command, ``y`` (the 9 action entries of ``protocols/AIBO.md``,
  each within its documented range), ``active`` (a control key or stick is held: in correct
  mode the teacher takes over only then), optional ``tick`` (lockstep: the tick it answers) and
  ``sent_ms`` (the page's wall clock at the key press, ms since the Unix epoch: the latency
  measure);
* ``mode``: ``mode`` one of :data:`MODES`;
* ``reset``: a new episode, optional ``location`` (0-12, else the next one);
* ``place_ball``: a new episode from the robot's pose with the ball at ``x``, ``y`` (m, in
  the field);
* ``record``: ``on`` true or false (a take with ``roger record``);
* ``checkpoint``: ask the daemon for a checkpoint;
* ``hello``: ``ticks`` true subscribes this connection to every tick (the scripted teacher).

:func:`parse` turns a frame into a :class:`PageInput` or raises :class:`Refused` with a reason
(:data:`REASONS`); :class:`Guard` also refuses floods (a token bucket per connection) and
counts every refusal by reason. The page's key map is :data:`KEYMAP`, sent to the page, which
composes ``y`` from the held keys (docs/teach.md).
"""

from __future__ import annotations

import json
import math
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

from protocols.aibo import ACTION_NAMES, ACTION_RANGES

__all__ = ["KEYMAP", "MAX_FRAME", "MODES", "REASONS", "Guard", "PageInput", "Refused", "parse"]

#: The three teaching modes (docs/teach.md).
MODES = ("demonstrate", "autonomous", "correct")
#: Largest text frame taken (bytes); bigger ones are refused as ``oversized``.
MAX_FRAME = 4096
#: Why an input is refused (the page's and ``roger teach``'s counters).
REASONS = ("oversized", "binary", "not_json", "not_an_object", "unknown_type", "bad_field",
           "not_finite", "out_of_range", "flood")
_TOLERANCE = 1e-9

#: The keyboard map: (``KeyboardEvent.code`` list, what it does, action entry, direction).
#: Walk keys command the entry's documented limit in that direction while held; head keys move
#: the head target at :data:`HEAD_RATE`; trap and kick set the action indicator.
KEYMAP: tuple[tuple[tuple[str, ...], str, str, int], ...] = (
    (("KeyW", "ArrowUp"), "walk forward", "walk_forward", 1),
    (("KeyS", "ArrowDown"), "walk backward", "walk_forward", -1),
    (("KeyA",), "step left", "walk_left", 1),
    (("KeyD",), "step right", "walk_left", -1),
    (("KeyQ", "ArrowLeft"), "turn left", "walk_turn", 1),
    (("KeyE", "ArrowRight"), "turn right", "walk_turn", -1),
    (("KeyI",), "head up", "head_tilt", 1),
    (("KeyK",), "head down", "head_tilt", -1),
    (("KeyJ",), "head left", "head_pan", 1),
    (("KeyL",), "head right", "head_pan", -1),
    (("KeyT",), "trap", "action", -1),
    (("Space",), "kick", "action", 1),
)
#: Head target speed while a head key is held (rad/s).
HEAD_RATE = 1.5
#: Turn rate of the turn keys (rad/s; the walk's limit is 2.1): a person steers better slower.
TURN_RATE = 1.2


class Refused(ValueError):
    """An input the session does not take; ``reason`` is one of :data:`REASONS`."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


@dataclass(frozen=True)
class PageInput:
    """One accepted input: its ``type`` and checked fields."""

    type: str
    y: tuple[float, ...] = ()
    active: bool = False
    tick: int | None = None
    sent_ms: float | None = None
    mode: str = ""
    location: int | None = None
    ball: tuple[float, float] | None = None
    on: bool = False
    ticks: bool = False
    received: float = field(default_factory=time.time)


def _number(m: dict[str, Any], name: str) -> float:
    v = m.get(name)
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise Refused("bad_field", f"{name!r} must be a number")
    if not math.isfinite(float(v)):
        raise Refused("not_finite", f"{name!r} must be finite")
    return float(v)


def _optional_int(m: dict[str, Any], name: str, lo: int, hi: int) -> int | None:
    v = m.get(name)
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, int):
        raise Refused("bad_field", f"{name!r} must be an integer")
    if not lo <= v <= hi:
        raise Refused("out_of_range", f"{name!r} must be in {lo}..{hi}, got {v}")
    return v


def _flag(m: dict[str, Any], name: str) -> bool:
    v = m.get(name, False)
    if not isinstance(v, bool):
        raise Refused("bad_field", f"{name!r} must be true or false")
    return v


def _command(m: dict[str, Any]) -> PageInput:
    y = m.get("y")
    if not isinstance(y, list) or len(y) != len(ACTION_NAMES):
        raise Refused("bad_field", f"'y' must be a list of {len(ACTION_NAMES)} numbers")
    values = []
    for name, v, (lo, hi) in zip(ACTION_NAMES, y, ACTION_RANGES, strict=True):
        if isinstance(v, bool) or not isinstance(v, int | float):
            raise Refused("bad_field", f"'y' entry {name} must be a number")
        f = float(v)
        if not math.isfinite(f):
            raise Refused("not_finite", f"'y' entry {name} must be finite")
        if not lo - _TOLERANCE <= f <= hi + _TOLERANCE:
            raise Refused("out_of_range", f"'y' entry {name} = {f:g} outside [{lo:g}, {hi:g}]")
        values.append(f)
    sent = _number(m, "sent_ms") if m.get("sent_ms") is not None else None
    return PageInput("command", y=tuple(values), active=_flag(m, "active"),
                     tick=_optional_int(m, "tick", 0, 2**62), sent_ms=sent)


def _place(m: dict[str, Any], half_length: float, half_width: float) -> PageInput:
    x, y = _number(m, "x"), _number(m, "y")
    if abs(x) > half_length or abs(y) > half_width:
        raise Refused("out_of_range", f"ball ({x:g}, {y:g}) m is outside the field "
                      f"(|x| <= {half_length:g}, |y| <= {half_width:g})")
    return PageInput("place_ball", ball=(x, y))


def parse(frame: str | bytes, *, locations: int = 13, half_length: float = 2.7,
          half_width: float = 1.8) -> PageInput:
    """One page frame as a :class:`PageInput`; :class:`Refused` if it is not one."""
    if isinstance(frame, bytes | bytearray | memoryview):
        raise Refused("binary", "frames must be JSON text")
    if len(frame) > MAX_FRAME and len(frame.encode("utf-8")) > MAX_FRAME:
        raise Refused("oversized", f"frame longer than {MAX_FRAME} bytes")
    try:
        m = json.loads(frame)
    except ValueError as exc:
        raise Refused("not_json", f"not JSON ({exc.__class__.__name__})") from None
    if not isinstance(m, dict):
        raise Refused("not_an_object", "a frame must be a JSON object")
    kind = m.get("type")
    if kind == "command":
        return _command(m)
    if kind == "mode":
        mode = m.get("mode")
        if mode not in MODES:
            raise Refused("bad_field", f"'mode' must be one of {MODES}")
        return PageInput("mode", mode=str(mode))
    if kind == "reset":
        return PageInput("reset", location=_optional_int(m, "location", 0, locations - 1))
    if kind == "place_ball":
        return _place(m, half_length, half_width)
    if kind == "record":
        return PageInput("record", on=_flag(m, "on"))
    if kind == "checkpoint":
        return PageInput("checkpoint")
    if kind == "hello":
        return PageInput("hello", ticks=_flag(m, "ticks"))
    raise Refused("unknown_type", f"unknown type {str(kind)[:40]!r}")


class Guard:
    """Per-connection flood control and the session's refusal counters.

    A token bucket of ``burst`` messages refilled at ``rate`` per second: a message that finds
    it empty is refused as ``flood`` (a page sends ~20 a second while a key is held; the
    scripted teacher one per tick, 30 a second in realtime and as fast as the loop in
    lockstep, hence the default of 2,000 a second)."""

    def __init__(self, counts: Counter[str], rate: float = 2000.0, burst: float = 400.0,
                 clock: Any = time.monotonic) -> None:
        self.counts = counts
        self.rate, self.burst = rate, burst
        self._tokens = burst
        self._clock = clock
        self._last = clock()

    def take(self) -> bool:
        """Whether one more message may pass now (one token taken)."""
        now = self._clock()
        self._tokens = min(self.burst, self._tokens + (now - self._last) * self.rate)
        self._last = now
        if self._tokens < 1.0:
            self.counts["flood"] += 1
            return False
        self._tokens -= 1.0
        return True

    def check(self, frame: str | bytes, **limits: Any) -> PageInput:
        """:func:`parse` behind the bucket; every refusal counted by reason."""
        if not self.take():
            raise Refused("flood", "more messages than the page may send")
        try:
            return parse(frame, **limits)
        except Refused as exc:
            self.counts[exc.reason] += 1
            raise
