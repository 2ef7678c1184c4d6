"""A robot's daemon state beside its model: the ``daemon`` arrays of a checkpoint.

One owner of that layout (docs/durability.md): the live daemon
(:class:`roger_daemon.daemon.robot.RobotRuntime`), replay's ``--save-checkpoint``, the start-up
checks and the experiment's model checkpoints all build and read it here, never by key.

The arrays:

* ``label_vocab`` (str) and ``label_codes`` (int32, one per learned pair, in learning order):
  the demonstrator's subtask label of every pair the model learned, as codes into the
  vocabulary. They name experts (majority label); the learner never sees them.
* ``queue_x``, ``queue_y``, ``queue_labels``, ``queue_ticks``: the training queue, pairs
  received but not yet learned, learned first after a restart;
* ``newest_pair_tick``, ``newest_pair_x``, ``newest_pair_y`` (one row, or none): the newest
  pair received (learned or queued), so that a restarted daemon recognises the sender's
  re-sent copy of it and does not learn it twice (docs/durability.md). Absent in checkpoints
  written before 2026-11-26: read as none.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from protocols.messages import Dims

__all__ = ["DAEMON_KEYS", "NEWEST_KEYS", "NewestPair", "Pair", "RobotState"]

#: The arrays of a checkpoint's daemon state.
DAEMON_KEYS = frozenset({"label_vocab", "label_codes", "queue_x", "queue_y", "queue_labels",
                         "queue_ticks"})
#: The optional arrays of the newest pair received (absent in older checkpoints).
NEWEST_KEYS = ("newest_pair_tick", "newest_pair_x", "newest_pair_y")


@dataclass(frozen=True, slots=True)
class Pair:
    """A training pair waiting in the queue (``t``: its perception's time, 0 if unknown)."""

    x: np.ndarray
    y: np.ndarray
    label: int
    tick: int
    t: float = 0.0


@dataclass(frozen=True, slots=True)
class NewestPair:
    """The newest pair a robot's daemon received: its tick, perception and action."""

    tick: int
    x: np.ndarray
    y: np.ndarray


@dataclass
class RobotState:
    """Label vocabulary, one label code per learned pair, the queued pairs and the newest
    pair received."""

    vocab: list[str] = field(default_factory=list)
    codes: npt.NDArray[np.int32] = field(default_factory=lambda: np.zeros(0, dtype=np.int32))
    queue: list[Pair] = field(default_factory=list)
    newest: NewestPair | None = None

    @classmethod
    def from_labels(cls, labels: Sequence[str], *, vocab: Sequence[str] = ()) -> RobotState:
        """The state of a model that learned pairs with these ``labels`` (empty queue).

        Codes index ``vocab`` first; labels not in it are appended in order of first use.
        """
        words = [str(v) for v in vocab]
        index = {w: i for i, w in enumerate(words)}
        codes = []
        for label in labels:
            if label not in index:
                index[label] = len(words)
                words.append(label)
            codes.append(index[label])
        return cls(words, np.array(codes, dtype=np.int32))

    @classmethod
    def from_arrays(cls, arrays: Mapping[str, npt.ArrayLike]) -> RobotState:
        """Read a checkpoint's daemon arrays; ``KeyError`` names a missing one, ``ValueError``
        arrays that do not fit together."""
        missing = sorted(DAEMON_KEYS - set(arrays))
        if missing:
            raise KeyError(f"daemon state lacks {', '.join(missing)}")
        queue = [Pair(np.array(x, dtype=np.float64), np.array(y, dtype=np.float64), int(lab),
                      int(tick))
                 for x, y, lab, tick in zip(np.asarray(arrays["queue_x"]),
                                            np.asarray(arrays["queue_y"]),
                                            np.asarray(arrays["queue_labels"]).tolist(),
                                            np.asarray(arrays["queue_ticks"]).tolist(),
                                            strict=True)]
        return cls([str(s) for s in np.asarray(arrays["label_vocab"]).tolist()],
                   np.asarray(arrays["label_codes"], dtype=np.int32).copy(), queue,
                   _newest_from(arrays))

    def to_arrays(self, dims: Dims) -> dict[str, np.ndarray]:
        """The checkpoint's daemon arrays (plain dtypes: no object arrays, no pickle)."""
        q = self.queue
        return {
            "label_vocab": np.array(self.vocab, dtype=np.str_) if self.vocab
            else np.zeros(0, dtype="<U1"),
            "label_codes": np.asarray(self.codes, dtype=np.int32).copy(),
            "queue_x": np.array([p.x for p in q], dtype=np.float64).reshape(len(q), dims.x),
            "queue_y": np.array([p.y for p in q], dtype=np.float64).reshape(len(q), dims.y),
            "queue_labels": np.array([p.label for p in q], dtype=np.int32),
            "queue_ticks": np.array([p.tick for p in q], dtype=np.int64),
            **_newest_arrays(self.newest, dims),
        }

    @property
    def n_learned(self) -> int:
        """Pairs the model learned (one label code each)."""
        return int(len(self.codes))

    def label(self, code: int) -> str:
        """The label of ``code`` ('' for a code outside the vocabulary)."""
        return self.vocab[code] if 0 <= code < len(self.vocab) else ""

    def labels(self) -> list[str]:
        """The label of every learned pair, in learning order."""
        return [self.label(c) for c in self.codes.tolist()]

    def queued_labels(self) -> list[str]:
        """The label of every queued pair, in queue order."""
        return [self.label(p.label) for p in self.queue]


def _newest_arrays(newest: NewestPair | None, dims: Dims) -> dict[str, np.ndarray]:
    rows = [] if newest is None else [newest]
    return {
        "newest_pair_tick": np.array([n.tick for n in rows], dtype=np.int64),
        "newest_pair_x": np.array([n.x for n in rows], dtype=np.float64).reshape(len(rows),
                                                                                  dims.x),
        "newest_pair_y": np.array([n.y for n in rows], dtype=np.float64).reshape(len(rows),
                                                                                  dims.y),
    }


def _newest_from(arrays: Mapping[str, npt.ArrayLike]) -> NewestPair | None:
    """The newest pair of a checkpoint's daemon arrays (``None``: none, or an older
    checkpoint without them)."""
    if not all(k in arrays for k in NEWEST_KEYS):
        return None
    ticks = np.asarray(arrays["newest_pair_tick"]).reshape(-1)
    x, y = np.asarray(arrays["newest_pair_x"]), np.asarray(arrays["newest_pair_y"])
    if ticks.size > 1 or x.ndim != 2 or y.ndim != 2 or len(x) != ticks.size \
            or len(y) != ticks.size:
        raise ValueError(f"daemon state's newest pair has {ticks.size} ticks, x of shape "
                         f"{x.shape} and y of shape {y.shape}; expected one row of each, "
                         "or none")
    if ticks.size == 0:
        return None
    return NewestPair(int(ticks[0]), np.array(x[0], dtype=np.float64),
                      np.array(y[0], dtype=np.float64))
