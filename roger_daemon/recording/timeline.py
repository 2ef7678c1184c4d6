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

The first segment starts at the metadata's ``start_updates`` (non-zero when the daemon resumed
from a checkpoint); when that checkpoint held unlearned pairs (metadata
``restored_queued_pairs``), the model learned those first, so the session's own pairs start at
``start_updates + restored_queued_pairs``. A pair's ``index`` is the model's ``n_learned`` just
before learning it (assuming the learner rejected no pair).
"""

from __future__ import annotations

from collections import Counter, OrderedDict
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import numpy.typing as npt

from protocols import keys as keyexpr
from protocols.errors import ProtocolError
from protocols.messages import (
    Action,
    Control,
    Dims,
    ExpertOutput,
    Perception,
    Prediction,
    Status,
    decode,
)
from roger_daemon.recording.events import decode_dropped, dropped_topic
from roger_daemon.recording.mcapio import LogReader, topics_of
from roger_daemon.recording.metadata import SessionInfo

__all__ = [
    "LEARNING_MODES",
    "LearnedPair",
    "PairTracker",
    "RecordedPrediction",
    "Segment",
    "Timeline",
    "read_timeline",
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


def _drop(tl: Timeline, seg: Segment, payload: bytes) -> None:
    """Apply a drop record: the newest formed pair of its tick was never learned."""
    try:
        tick = decode_dropped(payload)
    except ValueError:
        tl.invalid["bad_drop_record"] += 1
        return
    for i in range(len(seg.pairs) - 1, -1, -1):
        if seg.pairs[i].tick == tick:
            del seg.pairs[i]
            for j in range(i, len(seg.pairs)):  # renumber (normally nothing follows)
                seg.pairs[j] = replace(seg.pairs[j], index=seg.first_index + j)
            tl.dropped_recorded += 1
            return
    tl.dropped_unmatched += 1


def _robot_for(info: SessionInfo, topics: Iterable[str], robot: str | None) -> str:
    if robot:
        return robot
    if info.robot and info.robot not in ("*", "all"):
        return info.robot
    robots = set()
    for t in topics:
        try:
            r, kind = keyexpr.parse(t)
        except ProtocolError:
            continue
        if kind in ("perception", "action"):
            robots.add(r)
    if len(robots) == 1:
        return robots.pop()
    raise ValueError(
        f"cannot tell which robot to replay: the log has {sorted(robots) or 'none'}; pass --robot"
    )


def read_timeline(
    paths: Iterable[str | Path],
    *,
    robot: str | None = None,
    dims: Dims | None = None,
    mode: str | None = None,
    start_updates: int | None = None,
    predictions: bool = True,
) -> Timeline:
    """Read a session (its parts in order) into segments of learned pairs and predictions.

    ``robot``, ``dims``, ``mode`` and ``start_updates`` override the metadata (needed for files
    from ``roger record``, which has no learner metadata: dims then come from the first valid
    perception and action). ``predictions=False`` skips the recorded predictions (log-tail
    catch-up needs only the pairs; predictions are the costliest messages to decode).
    """
    files = [Path(p) for p in paths]
    if not files:
        raise ValueError("no files to read")
    readers = [LogReader(p) for p in files]
    # Metadata first (cheap: it is at the front of each file).
    from roger_daemon.recording.mcapio import read_metadata

    meta = read_metadata(files[0])
    info = SessionInfo.from_metadata(meta)
    if len(files) > 1:
        ids = {read_metadata(p).get("session_id", "") for p in files}
        if len(ids) > 1:
            raise ValueError(f"these files belong to {len(ids)} sessions; replay one at a time "
                             "(its parts in order)")
    topics: set[str] = set()
    if not robot and not (info.robot and info.robot not in ("*", "all")):
        for r in readers:
            for lm in LogReader(r.path).messages():
                topics.add(lm.topic)
    who = _robot_for(info, topics, robot)
    dims = dims or info.dims
    mode_now = mode or info.mode
    start = info.start_updates if start_updates is None else start_updates
    segments = [Segment(start_updates=start, after_reset=False,
                        queued=info.restored_queued_pairs if start_updates is None else 0)]
    tl = Timeline(
        info=info,
        robot=who,
        dims=dims,
        segments=segments,
        files=files,
        file_errors={},
        incomplete_files=[],
    )
    tl.pair_window = info.pair_window or DEFAULT_PAIR_WINDOW
    tracker = PairTracker(tl.pair_window)
    recent: OrderedDict[int, Perception] = OrderedDict()  # newest perception per tick (queries)
    last_dropped: int | None = None
    want = {keyexpr.key(who, k): k
            for k in ("perception", "action", "control", "prediction", "status")
            if predictions or k != "prediction"}
    drop_topic = dropped_topic(who)
    dx = dims.x if dims else None
    dy = dims.y if dims else None
    for reader in readers:
        for lm in reader.messages():
            kind = want.get(lm.topic)
            if kind is None:
                if lm.topic == drop_topic:
                    _drop(tl, segments[-1], lm.message.data)
                continue
            tl.messages += 1
            try:
                msg = decode(kind, lm.message.data, dims=Dims(dx, dy) if dx and dy else None,
                             robot=who)
            except ProtocolError as exc:
                tl.invalid[exc.reason] += 1
                continue
            t_ns = lm.message.log_time
            pair = None
            if isinstance(msg, Perception):
                if dx is None:
                    dx = msg.x.size
                elif msg.x.size != dx:
                    tl.invalid["wrong_dimension"] += 1
                    continue
                recent[msg.tick] = msg
                recent.move_to_end(msg.tick)
                if len(recent) > 4 * tracker.max_pending:
                    recent.popitem(last=False)
                if mode_now in LEARNING_MODES:
                    pair = tracker.perception(msg)
                else:
                    tl.ignored_not_learning += 1
            elif isinstance(msg, Action):
                if dy is None:
                    dy = msg.y.size
                elif msg.y.size != dy:
                    tl.invalid["wrong_dimension"] += 1
                    continue
                if mode_now in LEARNING_MODES:
                    pair = tracker.action(msg)
                else:
                    tl.ignored_not_learning += 1
            elif isinstance(msg, Control):
                if msg.op == "mode":
                    mode_now = msg.mode
                elif msg.op == "reset":
                    segments.append(Segment(start_updates=0, after_reset=True))
                    tracker = PairTracker(tl.pair_window)
            elif isinstance(msg, Prediction):
                q = recent.get(msg.tick)
                if q is None:
                    tl.predictions_without_query += 1
                    continue
                segments[-1].predictions.append(
                    RecordedPrediction(
                        tick=msg.tick,
                        updates=msg.updates,
                        x=q.x,
                        mean=msg.mean,
                        var=msg.var,
                        expert=msg.expert,
                        multimap=msg.multimap,
                        mode=msg.mode,
                        log_time_ns=t_ns,
                    )
                )
            elif isinstance(msg, Status):
                if last_dropped is not None and msg.dropped > last_dropped:
                    tl.daemon_dropped += msg.dropped - last_dropped
                last_dropped = msg.dropped
            if pair is not None:
                p, a = pair
                seg = segments[-1]
                seg.pairs.append(
                    LearnedPair(
                        index=seg.end_updates,
                        tick=p.tick,
                        x=p.x,
                        y=a.y,
                        label=a.label,
                        log_time_ns=t_ns,
                    )
                )
        if reader.error:
            tl.file_errors[str(reader.path)] = reader.error
        if not reader.complete:
            tl.incomplete_files.append(str(reader.path))
    if tl.dims is None and dx is not None and dy is not None:
        tl.dims = Dims(dx, dy)
    tl.unpaired = tracker.pending
    if robot and tl.messages == 0 and not tl.file_errors:
        raise ValueError(robot_absent(files, robot) or f"robot {robot!r}: nothing to replay")
    return tl


def robot_absent(files: Iterable[Path], robot: str) -> str:
    """Why ``robot`` cannot be replayed from ``files`` ("" if it has messages there): the
    message names the robots the log does have."""
    robots = set()
    files = list(files)
    for f in files:
        for t in topics_of(f):
            try:
                robots.add(keyexpr.parse(t)[0])
            except ProtocolError:
                continue
    if robot in robots:
        return ""
    return (f"robot {robot!r} has no message in {', '.join(map(str, files))}; "
            f"the log has robot(s) {sorted(robots) or 'none'} (--robot ID)")
