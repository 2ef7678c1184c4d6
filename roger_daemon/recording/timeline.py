"""From a recorded session to what the learner saw: learned pairs and recorded predictions.

The rules mirror the daemon's loop (``roger_daemon.robot.RobotRuntime`` and
``roger_daemon.service.Service``), read in the log's write order, which is the order the
daemon handled messages in (it records each message as it takes it off its inbox, before
routing it, and each prediction and status as it publishes it):

* **Pairing** (:class:`PairTracker`), only while the mode learns (``learn``,
  ``learn+predict``): ``perception(t)`` and ``action(t)`` of the robot wait for each other by
  tick in two insertion-ordered buffers of ``pair_window`` entries (the session's, default 64);
  the second to arrive forms a pair; the newest perception of a tick wins; a tick pairs once.
  In the other modes perceptions and actions are not buffered at all. Payloads that fail
  ``protocols.decode`` with the session's dims are skipped.
* **Learning order** = pair formation order (the daemon's FIFO training queue). A pair the
  daemon dropped because its queue was full is named by a record on
  ``roger/<robot>/daemon/dropped`` (:mod:`~roger_daemon.recording.events`) right after the
  message that completed it, and is removed (:attr:`Timeline.dropped_recorded`). Logs from
  daemons that did not write these records only show the ``dropped`` counter of the status
  messages (:attr:`Timeline.daemon_dropped`); replay warns when that counter says more.
* **Mode** starts as the metadata's ``mode`` and follows ``control`` messages ``op=mode``.
* **Reset** (``control`` ``op=reset``) starts a new :class:`Segment` with a fresh model
  (``n_learned`` 0, same params and seed) and empties the pairing buffers.
* **Predictions**: each recorded prediction is tied to the newest perception of its tick (its
  query) and to its ``updates`` (the model's ``n_learned`` when it was computed).

:func:`~roger_daemon.recording.session_read.read_timeline` applies these rules to a session's
files; this module holds the rules' data.

The first segment starts at the metadata's ``start_updates`` (non-zero when the daemon resumed
from a checkpoint); when that checkpoint held unlearned pairs (metadata
``restored_queued_pairs``), the model learned those first, so the session's own pairs start at
``start_updates + restored_queued_pairs``. A pair's ``index`` is the model's ``n_learned`` just
before learning it (assuming the learner rejected no pair).
"""

from __future__ import annotations

from collections import Counter, OrderedDict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt

from protocols.messages import Action, Dims, ExpertOutput, Perception
from roger_daemon.recording.metadata import SessionInfo

__all__ = [
    "LEARNING_MODES",
    "LearnedPair",
    "PairTracker",
    "RecordedPrediction",
    "Segment",
    "Timeline",
]

FloatArray = npt.NDArray[np.float64]

#: Modes in which the daemon pairs and learns.
LEARNING_MODES = ("learn", "learn+predict")
#: The daemon's default pairing window (``[daemon] pair_window``).
DEFAULT_PAIR_WINDOW = 64


@dataclass(frozen=True)
class LearnedPair:
    """One training pair, as the learner got it."""

    index: int  # model.n_learned just before this pair was learned
    tick: int
    x: FloatArray
    y: FloatArray
    label: str
    log_time_ns: int


@dataclass(frozen=True)
class RecordedPrediction:
    """A prediction from the log, with the perception it answered."""

    tick: int
    updates: int
    x: FloatArray
    mean: FloatArray
    var: FloatArray
    expert: int
    multimap: tuple[ExpertOutput, ...]
    mode: str
    log_time_ns: int


@dataclass
class Segment:
    """A stretch of the session learned by one model (the session start, or after a reset)."""

    start_updates: int
    after_reset: bool
    pairs: list[LearnedPair] = field(default_factory=list)
    predictions: list[RecordedPrediction] = field(default_factory=list)
    #: pairs restored from the checkpoint's queue, learned before ``pairs`` (not in this log)
    queued: int = 0

    @property
    def first_index(self) -> int:
        """``n_learned`` before this segment's first logged pair."""
        return self.start_updates + self.queued

    @property
    def end_updates(self) -> int:
        """``n_learned`` of the model after the last pair."""
        return self.start_updates + self.queued + len(self.pairs)


class PairTracker:
    """Pair perception and action of one robot by tick (the daemon's rule; see module doc).

    The daemon can use this very class, which guarantees that replay pairs the same way.
    """

    def __init__(self, max_pending: int = DEFAULT_PAIR_WINDOW) -> None:
        self.max_pending = max_pending
        self._perc: OrderedDict[int, Perception] = OrderedDict()
        self._act: OrderedDict[int, Action] = OrderedDict()
        self.dropped_perceptions = 0
        self.dropped_actions = 0

    def perception(self, msg: Perception) -> tuple[Perception, Action] | None:
        """Take a perception; return the pair it completes, if any."""
        act = self._act.pop(msg.tick, None)
        if act is not None:
            return msg, act
        self._perc[msg.tick] = msg
        self._perc.move_to_end(msg.tick)
        while len(self._perc) > self.max_pending:
            self._perc.popitem(last=False)
            self.dropped_perceptions += 1
        return None

    def action(self, msg: Action) -> tuple[Perception, Action] | None:
        """Take an action; return the pair it completes, if any."""
        perc = self._perc.pop(msg.tick, None)
        if perc is not None:
            return perc, msg
        self._act[msg.tick] = msg
        self._act.move_to_end(msg.tick)
        while len(self._act) > self.max_pending:
            self._act.popitem(last=False)
            self.dropped_actions += 1
        return None

    @property
    def pending(self) -> tuple[int, int]:
        """(perceptions, actions) waiting for their other half."""
        return len(self._perc), len(self._act)


@dataclass
class Timeline:
    """Everything replay and catch-up need from one session's files."""

    info: SessionInfo
    robot: str
    dims: Dims | None
    segments: list[Segment]
    files: list[Path]
    file_errors: dict[str, str]
    incomplete_files: list[str]
    messages: int = 0
    invalid: Counter[str] = field(default_factory=Counter)
    ignored_not_learning: int = 0  # perceptions/actions that arrived while not learning
    unpaired: tuple[int, int] = (0, 0)  # (perceptions, actions) left without a partner
    predictions_without_query: int = 0
    pair_window: int = DEFAULT_PAIR_WINDOW
    daemon_dropped: int = 0  # pairs the daemon dropped (queue full), from its status counter
    dropped_recorded: int = 0  # drops named by drop records (those pairs are removed)
    dropped_unmatched: int = 0  # drop records naming no formed pair (ignored)

    @property
    def unexplained_drops(self) -> int:
        """Drops the status counter shows but no drop record names (replay cannot be exact)."""
        return max(0, self.daemon_dropped - self.dropped_recorded)

    @property
    def pairs(self) -> list[LearnedPair]:
        """Learned pairs of the last segment (the final model's history)."""
        return self.segments[-1].pairs

    @property
    def resets(self) -> int:
        """Number of resets in the session."""
        return len(self.segments) - 1
