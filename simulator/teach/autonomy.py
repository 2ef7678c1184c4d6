"""The robot's own command in ``roger teach``: ROGER's experts chosen by learned transitions.

:class:`Autonomy` keeps a :class:`~roger_daemon.fsm.LearnedFSM` over the daemon's experts
(docs/autonomy.md): it learns online from every tick of the session (a teacher's tick
teaches the transition into the expert most responsible for the teacher's command in the
daemon's multimap, a robot's tick only advances the memories) and acts on the daemon's
newest multimap. :meth:`Autonomy.refit` replaces it by one fitted on the whole stream so far
against a checkpoint of the daemon's model (:func:`roger_daemon.fsm.fit_fsm`): the online
one saw each tick against the model of that moment, whose experts have changed since.
Nothing here reads a label or the hand-coded controller. Before anything was learned the
robot holds still; a multimap with none of the learned successors acts on the paper's gate
argmax (``LearnedFSM.choose``).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from protocols import Prediction
from protocols.aibo import DIMS
from roger_daemon.fsm import LearnedFSM, aibo_memory, fit_fsm, responsible_expert
from roger_daemon.learner.prediction import MultimapTable

__all__ = ["Autonomy", "hold_command", "table_of"]

FloatArray = npt.NDArray[np.float64]
#: What the page says drives the robot in autonomous and correct modes.
KIND = "learned transitions over ROGER's experts (roger_daemon.fsm.LearnedFSM), no HCC"


def table_of(pred: Prediction) -> MultimapTable:
    """The daemon's multimap of one prediction as the learner's table (what the FSM reads)."""
    mm = pred.multimap
    if not mm:
        return MultimapTable.empty(DIMS.y)
    return MultimapTable([int(e.expert) for e in mm], [float(e.p) for e in mm],
                         np.array([e.mean for e in mm], dtype=np.float64),
                         np.array([e.var for e in mm], dtype=np.float64),
                         [int(e.n) for e in mm])


def hold_command(x: npt.ArrayLike) -> FloatArray:
    """Stand still, head and tail where they are, no motion (what the simulator holds)."""
    y = np.zeros(DIMS.y)
    y[3:8] = np.asarray(x, dtype=np.float64)[18:23]
    return y


@dataclass
class _Stream:
    """Every executed tick of the session: perception, command, taught, episode start."""

    x: list[FloatArray]
    y: list[FloatArray]
    taught: list[bool]
    start: list[bool]


class Autonomy:
    """Online learned transitions, refitted on request (module docstring). Thread-safe: the
    loop calls :meth:`observe` and :meth:`act`, a background thread :meth:`refit`."""

    kind = KIND

    def __init__(self, max_ticks: int = 500_000) -> None:
        self.spec = aibo_memory()
        self.fsm = LearnedFSM(self.spec)
        self.max_ticks = max_ticks
        self.stream = _Stream([], [], [], [])
        self._lock = threading.Lock()
        self.fitted: dict[str, Any] = {"fit": "online", "ticks": 0, "updates": 0}
        self.refitting = False

    def observe(self, x: FloatArray, y: FloatArray, pred: Prediction | None, taught: bool,
                start: bool) -> None:
        """One executed tick: learn its transition if the teacher commanded it."""
        state = -1
        if taught and pred is not None and pred.multimap:
            state = responsible_expert(table_of(pred), y)
        with self._lock:
            self.fsm.observe(x, y, state, start)
            if len(self.stream.x) < self.max_ticks:
                self.stream.x.append(np.array(x, dtype=np.float64))
                self.stream.y.append(np.array(y, dtype=np.float64))
                self.stream.taught.append(bool(taught))
                self.stream.start.append(bool(start))

    def reset(self) -> None:
        """A new episode for the acting side."""
        with self._lock:
            self.fsm.reset()

    def act(self, x: FloatArray, pred: Prediction | None) -> tuple[FloatArray, int, str]:
        """(command, expert, how) for this tick; committed to the acting memories."""
        with self._lock:
            if pred is None or not pred.multimap:
                y = hold_command(x)
                self.fsm.commit(y)
                return y, -1, "hold: nothing learned yet" if pred else "hold: no prediction"
            y = self.fsm.act(x, table_of(pred))
            if not np.all(np.isfinite(y)):
                y = hold_command(x)
                self.fsm.commit(y)
            return y, self.fsm.state, "learned transitions"

    def commit(self, y: FloatArray) -> None:
        """The command actually executed (the teacher's, in a correction)."""
        with self._lock:
            self.fsm.commit(y)

    def ticks(self) -> int:
        """Ticks observed so far."""
        return len(self.stream.x)

    def refit(self, model: Any, updates: int) -> None:
        """Fit the transitions anew over ``model``'s experts on the whole stream so far."""
        with self._lock:
            n = len(self.stream.x)
            if n == 0:
                return
            x, y = np.array(self.stream.x[:n]), np.array(self.stream.y[:n])
            taught = np.array(self.stream.taught[:n])
            start = np.array(self.stream.start[:n])
        fitted = fit_fsm(model, x, y, start, self.spec, learn=taught)
        with self._lock:
            # ticks observed meanwhile: taught against the daemon's multimap of their moment
            # would need their predictions; they advance the memories only
            for t in range(n, len(self.stream.x)):
                fitted.observe(self.stream.x[t], self.stream.y[t], -1, self.stream.start[t])
            self.fsm = fitted
            self.fitted = {"fit": "refitted on a checkpoint", "ticks": n, "updates": updates}
