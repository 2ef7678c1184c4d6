"""The robot's own command in ``roger teach``: ROGER's experts chosen by learned transitions.

The daemon runs the ``roger+fsm`` model (docs/autonomy.md, *Learned in the daemon*): every
pair it learns also teaches its :class:`~roger_daemon.fsm.LearnedFSM`, the state being the
expert its MAP particle gave the pair. :class:`Autonomy` plays those transitions as ``roger
play`` does (:class:`~roger_daemon.fsm.player.Player`, loaded from a checkpoint of the
daemon's model): each tick, the daemon's multimap for the perception goes in and the chosen
expert's mean comes out. :meth:`Autonomy.load` is called on entering autonomous or correct
mode and after each correction, so the robot acts on what it was just taught. Nothing here
reads a label or the hand-coded controller. Until a checkpoint with transitions is loaded the
robot holds still.
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from protocols import Prediction
from protocols.aibo import DIMS

__all__ = ["KIND", "Autonomy", "hold_command"]

FloatArray = npt.NDArray[np.float64]
#: What the page says drives the robot in autonomous and correct modes.
KIND = ("learned transitions over ROGER's experts (the daemon's roger+fsm model, played as "
        "roger play does), no HCC")


def hold_command(x: npt.ArrayLike) -> FloatArray:
    """Stand still, head and tail where they are, no motion (what the simulator holds)."""
    y = np.zeros(DIMS.y)
    y[3:8] = np.asarray(x, dtype=np.float64)[18:23]
    return y


class Autonomy:
    """The learned transitions of the daemon's newest checkpoint, played (module docstring).
    Thread-safe: the loop calls :meth:`act` and :meth:`commit`, a background thread
    :meth:`load`."""

    kind = KIND

    def __init__(self) -> None:
        self.player: Any = None
        self._lock = threading.Lock()
        self.fitted: dict[str, Any] = {"fit": "none yet", "updates": 0, "checkpoint": ""}
        self.loading = False

    def load(self, checkpoint: str | Path, updates: int, robot: str = "aibo") -> None:
        """Play the transitions of ``checkpoint`` from now on (``ValueError``: it has none)."""
        from roger_daemon.fsm.player import load_player

        player = load_player(checkpoint, robot)
        with self._lock:
            self.player = player
            self.fitted = {"fit": "loaded", "updates": int(updates),
                           "checkpoint": Path(checkpoint).name}

    def reset(self) -> None:
        """A new episode: the transitions back to their start state."""
        with self._lock:
            if self.player is not None:
                self.player.reset()

    def act(self, x: FloatArray, pred: Prediction | None) -> tuple[FloatArray, int, str]:
        """(command, learned state, how) for this tick; committed to the player's memories."""
        hold = hold_command(x)
        with self._lock:
            if self.player is None:
                return hold, -1, "hold: no transitions loaded yet"
            if pred is None:
                self.player.commit(hold)
                return hold, self.player.state, "hold: no prediction"
            y, how = self.player.command(x, pred.multimap, hold)
            if not np.all(np.isfinite(y)):
                y = hold
                self.player.commit(y)
            return y, int(self.player.state), "learned transitions" if how == "learned" else how

    def commit(self, y: FloatArray) -> None:
        """The command actually executed (the teacher's, in a correction)."""
        with self._lock:
            if self.player is not None:
                self.player.commit(y)
