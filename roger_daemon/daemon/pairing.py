"""Pairing perception with action by tick: the one implementation of the daemon's rule.

``perception(t)`` and ``action(t)`` of one robot meet by tick in two small insertion-ordered
buffers of ``window`` entries: whichever half arrives first waits, the second completes the
pair; a newer perception of a waiting tick replaces the older one; a tick pairs once (its
waiting half is taken). When a buffer is full its oldest entry is evicted and counted.

:class:`~roger_daemon.daemon.robot.RobotRuntime` pairs with it while its mode learns, and the reader
of version-1 session logs (which hold no decision records) re-derives the learned pairs with
it (:mod:`roger_daemon.recording.read_inputs`), so the two cannot disagree.

>>> from protocols.messages import Action, Perception
>>> p = Pairing(window=2)
>>> p.action(Action("r", 1, 0.0, y=[1.0])) is None
True
>>> pair = p.perception(Perception("r", 1, 0.0, x=[0.5]))
>>> (pair[0].tick, pair[1].tick), p.pending
((1, 1), (0, 0))
"""

from __future__ import annotations

from collections import OrderedDict

from protocols.messages import Action, Perception
from roger_daemon.config.settings import DaemonConfig

__all__ = ["DEFAULT_PAIR_WINDOW", "LEARN_MODES", "PREDICT_MODES", "Pairing"]

#: The daemon's default pairing window (``[daemon] pair_window``).
DEFAULT_PAIR_WINDOW = DaemonConfig.pair_window
#: Modes in which the daemon pairs and learns.
LEARN_MODES = ("learn", "learn+predict")
#: Modes in which the daemon answers perceptions with predictions.
PREDICT_MODES = ("predict", "learn+predict")


class Pairing:
    """The two waiting buffers of one robot (see the module doc).

    ``evicted_perceptions``/``evicted_actions`` count halves pushed out of a full buffer;
    ``last_evicted_action`` is the tick of the newest evicted action (-1: none yet).
    """

    def __init__(self, window: int = DEFAULT_PAIR_WINDOW) -> None:
        self.window = window
        self._perceptions: OrderedDict[int, Perception] = OrderedDict()
        self._actions: OrderedDict[int, Action] = OrderedDict()
        self.evicted_perceptions = 0
        self.evicted_actions = 0
        self.last_evicted_action = -1

    def perception(self, msg: Perception) -> tuple[Perception, Action] | None:
        """Take a perception; return the pair it completes, if any."""
        act = self._actions.pop(msg.tick, None)
        if act is not None:
            return msg, act
        self._perceptions[msg.tick] = msg
        self._perceptions.move_to_end(msg.tick)
        while len(self._perceptions) > self.window:
            self._perceptions.popitem(last=False)
            self.evicted_perceptions += 1
        return None

    def action(self, msg: Action) -> tuple[Perception, Action] | None:
        """Take an action; return the pair it completes, if any."""
        perc = self._perceptions.pop(msg.tick, None)
        if perc is not None:
            return perc, msg
        self._actions[msg.tick] = msg
        self._actions.move_to_end(msg.tick)
        while len(self._actions) > self.window:
            self.last_evicted_action, _ = self._actions.popitem(last=False)
            self.evicted_actions += 1
        return None

    def clear(self) -> None:
        """Forget every waiting half (a reset)."""
        self._perceptions.clear()
        self._actions.clear()

    @property
    def pending(self) -> tuple[int, int]:
        """(perceptions, actions) waiting for their other half."""
        return len(self._perceptions), len(self._actions)
