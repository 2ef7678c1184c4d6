"""The scripted teacher: the hand-coded controller teaching through the page's own channel.

:class:`ScriptedTeacher` connects to a running ``roger teach`` as a page does (the same
WebSocket, the same ``command`` frames a page sends for held keys, checked by the same
channel) and answers every tick (``hello`` with ``ticks``; in lockstep the loop waits for each
answer). It runs the HCC (:class:`~simulator.controllers.hcc.HCC`) on each tick's perception:

* **demonstrate**: the HCC's command, every tick (a key held all the time);
* **correct**: the robot drives; the teacher takes over (``active``) when the robot's command
  disagrees with the HCC's (:func:`disagrees`) and keeps the key down for at least
  :data:`HOLD_TICKS`, as a person would; otherwise it lets the robot drive;
* **evaluate**: autonomous mode, one episode from each start location, goals counted.

The HCC's subtask labels never leave this process: the channel has no label.
"""

from __future__ import annotations

import json
import time
from collections import Counter
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from protocols.aibo import ACTION_RANGES, decode_indicator
from simulator.controllers.hcc import HCC

__all__ = ["HOLD_TICKS", "ScriptedTeacher", "disagrees"]

#: A correction lasts at least this many ticks (half a second), as a held key does.
HOLD_TICKS = 15
_WALK = slice(0, 3)
_SCALE = np.array([hi - lo for lo, hi in ACTION_RANGES[:3]])
_LO = np.array([lo for lo, _ in ACTION_RANGES])
_HI = np.array([hi for _, hi in ACTION_RANGES])


def disagrees(robot: np.ndarray, teacher: np.ndarray, threshold: float = 0.25) -> bool:
    """Whether the robot's command is wrong enough for the teacher to take over: a walk entry
    off by more than ``threshold`` of its range, or another motion (kick / trap / none)."""
    walk = np.abs(np.asarray(robot[_WALK]) - np.asarray(teacher[_WALK])) / _SCALE
    motion = decode_indicator(float(robot[-1])) != decode_indicator(float(teacher[-1]))
    return bool(np.any(walk > threshold) or motion)


class ScriptedTeacher:
    """The HCC as a page's user (module docstring). ``url`` is the page's ``http://`` one."""

    def __init__(self, url: str, hcc: HCC | None = None, timeout_s: float = 120.0) -> None:
        from websockets.sync.client import connect

        ws_url = url.replace("http://", "ws://").rstrip("/") + "/ws"
        self.ws = connect(ws_url, compression=None, proxy=None, max_size=2**22,
                          open_timeout=30, ping_interval=None)
        self.hcc = hcc or HCC()
        self.timeout_s = timeout_s
        self.counts: Counter[str] = Counter()
        self.state: dict[str, Any] = {}
        self.episodes: list[dict[str, Any]] = []
        self._hold = 0
        self.send({"type": "hello", "ticks": True})

    def close(self) -> None:
        """Close the WebSocket."""
        self.ws.close()

    def send(self, msg: dict[str, Any]) -> None:
        """One frame to the page's channel."""
        self.ws.send(json.dumps(msg))
        self.counts["sent"] += 1

    def _next(self) -> dict[str, Any]:
        m: dict[str, Any] = json.loads(self.ws.recv(timeout=self.timeout_s))
        kind = m.get("type")
        if kind == "state":
            self.state = m
        elif kind == "episode":
            self.episodes.append(m)
        elif kind == "refused":
            self.counts[f"refused_{m.get('reason')}"] += 1
        return m

    def until(self, done: Callable[[dict[str, Any]], bool], on_tick: Callable[[dict[str, Any]],
              None] | None = None) -> dict[str, Any]:
        """Read frames, answering ticks with ``on_tick``, until ``done(frame)``."""
        while True:
            m = self._next()
            if m.get("type") == "tick" and on_tick is not None:
                on_tick(m)
            if done(m):
                return m

    # -- answering ticks ---------------------------------------------------------------------

    def _decide(self, m: dict[str, Any]) -> np.ndarray:
        if m["start"]:
            self.hcc.reset()
            self._hold = 0
        y, _label = self.hcc.decide(np.asarray(m["x"], dtype=np.float64))
        clipped: np.ndarray = np.clip(y, _LO, _HI)
        return clipped

    def demonstrate_tick(self, m: dict[str, Any]) -> None:
        """Demonstrate mode: the HCC's command drives."""
        if m["mode"] != "demonstrate":
            return
        y = self._decide(m)
        self.hcc.commit(y)
        self.send({"type": "command", "tick": m["tick"], "y": y.tolist(), "active": True,
                   "sent_ms": time.time() * 1e3})
        self.counts["demonstrated"] += 1

    def correct_tick(self, m: dict[str, Any]) -> None:
        """Correct mode: take over while the robot disagrees (at least HOLD_TICKS)."""
        if m["mode"] != "correct":
            return
        y = self._decide(m)
        robot = np.asarray(m["robot_y"], dtype=np.float64)
        if disagrees(robot, y):
            if self._hold == 0:
                self.counts["interventions"] += 1
            self._hold = max(self._hold, HOLD_TICKS)
        active = self._hold > 0
        self._hold = max(0, self._hold - 1)
        self.hcc.commit(y if active else robot)
        self.send({"type": "command", "tick": m["tick"], "y": y.tolist(), "active": active,
                   "sent_ms": time.time() * 1e3})
        self.counts["corrected" if active else "let_drive"] += 1

    # -- the phases --------------------------------------------------------------------------

    def teach(self, mode: str, ticks: int, location: int = 0) -> None:
        """``ticks`` ticks of ``mode`` (demonstrate or correct), from a new episode."""
        answer = self.demonstrate_tick if mode == "demonstrate" else self.correct_tick
        self.send({"type": "mode", "mode": mode})
        self.send({"type": "reset", "location": location})
        seen = [0]

        def on_tick(m: dict[str, Any]) -> None:
            if m["mode"] == mode:
                answer(m)
                seen[0] += 1

        self.until(lambda m: seen[0] >= ticks, on_tick)

    def wait_transitions(self, timeout_s: float = 600.0) -> dict[str, Any]:
        """Enter autonomous mode; the state once the newest transitions are loaded."""
        end = time.monotonic() + timeout_s
        self.send({"type": "mode", "mode": "autonomous"})
        started = [False]

        def loaded(m: dict[str, Any]) -> bool:
            fsm = m.get("fsm", {}) if m.get("type") == "state" else {}
            started[0] = started[0] or bool(fsm.get("loading"))
            return (started[0] and fsm.get("fit") == "loaded" and not fsm.get("loading")) \
                or time.monotonic() > end

        return self.until(loaded)

    def evaluate(self, locations: Sequence[int]) -> list[dict[str, Any]]:
        """One autonomous episode from each location; their records."""
        self.send({"type": "mode", "mode": "autonomous"})
        out = []
        for loc in locations:
            self.send({"type": "reset", "location": loc})
            first = len(self.episodes)

            def ended(m: dict[str, Any], loc: int = loc, first: int = first) -> bool:
                return (m.get("type") == "episode" and len(self.episodes) > first
                        and m["location"] == loc and m["outcome"] != "stopped"
                        and m["mode"] == "autonomous")

            out.append(self.until(ended))
        return out

