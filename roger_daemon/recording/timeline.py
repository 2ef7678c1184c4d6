"""From a recorded session to what the learner saw: learned pairs and recorded predictions.

:func:`~roger_daemon.recording.session_read.read_timeline` reads a session's files in write
order (the order the daemon handled messages in) into a :class:`Timeline`: one
:class:`Segment` per stretch learned by one model (the session's start, then one per reset),
each with its learned pairs in learning order and the recorded predictions computed on it.

* **Version-2 logs** (metadata ``format`` ``roger-session/2``, written by daemons that record
  their decisions, :mod:`protocols.decisions`): each ``learned`` record is one pair, with its
  ``x``, ``y``, label and the model's ``n_learned`` after it; each ``reset`` record starts a
  segment; ``model`` records carry the digests of the checkpoints' models (kept on the
  segment, :attr:`Segment.digests`, so that replay can check it rebuilt the same model).
  Nothing is re-derived: pairs the daemon dropped are simply not there.
* **Version-1 logs** (older daemons, ``roger record``): the pairs are re-derived from the
  recorded perceptions and actions with the daemon's own pairing rule
  (:mod:`roger_daemon.daemon.pairing`) by :mod:`roger_daemon.recording.read_inputs`, which documents
  the rules (modes, resets, drop records).
* **Predictions** (both): each recorded prediction is tied to the newest perception of its
  tick (its query) and to its ``updates`` (the model's ``n_learned`` when it was computed).

The first segment starts at the metadata's ``start_updates`` (non-zero when the daemon resumed
from a checkpoint). In a version-1 log, when that checkpoint held unlearned pairs (metadata
``restored_queued_pairs``), the model learned those first without the log naming them, so the
session's own pairs start at ``start_updates + restored_queued_pairs`` (:attr:`Segment.queued`);
a version-2 log names them as ``learned`` records. A pair's ``index`` is the model's
``n_learned`` just before learning it.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt

from protocols.messages import Dims, ExpertOutput
from roger_daemon.daemon.pairing import DEFAULT_PAIR_WINDOW
from roger_daemon.recording.metadata import SessionInfo

__all__ = [
    "LearnedPair",
    "ModelCheck",
    "RecordedPrediction",
    "Segment",
    "Timeline",
]

FloatArray = npt.NDArray[np.float64]


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


@dataclass(frozen=True)
class ModelCheck:
    """A checkpoint's model digest recorded by the daemon (a version-2 ``model`` record)."""

    updates: int
    digest: str
    chain: str


@dataclass
class Segment:
    """A stretch of the session learned by one model (the session start, or after a reset)."""

    start_updates: int
    after_reset: bool
    pairs: list[LearnedPair] = field(default_factory=list)
    predictions: list[RecordedPrediction] = field(default_factory=list)
    #: pairs restored from the checkpoint's queue, learned before ``pairs`` (not in this log)
    queued: int = 0
    #: the checkpoints' model digests the daemon recorded in this segment (version 2)
    digests: list[ModelCheck] = field(default_factory=list)

    @property
    def first_index(self) -> int:
        """``n_learned`` before this segment's first logged pair."""
        return self.start_updates + self.queued

    @property
    def end_updates(self) -> int:
        """``n_learned`` of the model after the last pair."""
        return self.start_updates + self.queued + len(self.pairs)


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
    decisions: bool = False  # the pairs come from the daemon's decision records (version 2)

    @property
    def unexplained_drops(self) -> int:
        """Drops the status counter shows but no drop record names (replay cannot be exact;
        never with decision records, which name every learned pair)."""
        if self.decisions:
            return 0
        return max(0, self.daemon_dropped - self.dropped_recorded)

    @property
    def pairs(self) -> list[LearnedPair]:
        """Learned pairs of the last segment (the final model's history)."""
        return self.segments[-1].pairs

    @property
    def resets(self) -> int:
        """Number of resets in the session."""
        return len(self.segments) - 1
