"""Read a recorded session into a :class:`~roger_daemon.recording.timeline.Timeline`.

The rules (pairing, learning order, mode, reset, predictions, drops) are described in
:mod:`roger_daemon.recording.timeline`; :func:`read_timeline` applies them to the messages of
a session's files in write order, one handler per message kind (:class:`_Reading`).
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Iterable
from dataclasses import replace
from pathlib import Path

from protocols import keys as keyexpr
from protocols.errors import ProtocolError
from protocols.messages import (
    Action,
    Control,
    Dims,
    Message,
    Perception,
    Prediction,
    Status,
    decode,
)
from roger_daemon.recording.events import decode_dropped, dropped_topic
from roger_daemon.recording.mcapio import LogMessage, LogReader, read_metadata, topics_of
from roger_daemon.recording.metadata import SessionInfo
from roger_daemon.recording.timeline import (
    DEFAULT_PAIR_WINDOW,
    LEARNING_MODES,
    LearnedPair,
    PairTracker,
    RecordedPrediction,
    Segment,
    Timeline,
)

__all__ = ["read_timeline", "robot_absent"]

_KINDS = ("perception", "action", "control", "prediction", "status")


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
    info = SessionInfo.from_metadata(read_metadata(files[0]))
    if len(files) > 1:
        ids = {read_metadata(p).get("session_id", "") for p in files}
        if len(ids) > 1:
            raise ValueError(f"these files belong to {len(ids)} sessions; replay one at a time "
                             "(its parts in order)")
    topics: set[str] = set()
    if not robot and not (info.robot and info.robot not in ("*", "all")):
        for r in readers:
            topics.update(lm.topic for lm in LogReader(r.path).messages())
    start = info.start_updates if start_updates is None else start_updates
    first = Segment(start_updates=start, after_reset=False,
                    queued=info.restored_queued_pairs if start_updates is None else 0)
    tl = Timeline(info=info, robot=_robot_for(info, topics, robot), dims=dims or info.dims,
                  segments=[first], files=files, file_errors={}, incomplete_files=[])
    tl.pair_window = info.pair_window or DEFAULT_PAIR_WINDOW
    reading = _Reading(tl, mode or info.mode, predictions)
    for reader in readers:
        for lm in reader.messages():
            reading.message(lm)
        if reader.error:
            tl.file_errors[str(reader.path)] = reader.error
        if not reader.complete:
            tl.incomplete_files.append(str(reader.path))
    reading.finish()
    if robot and tl.messages == 0 and not tl.file_errors:
        raise ValueError(robot_absent(files, robot) or f"robot {robot!r}: nothing to replay")
    return tl


class _Reading:
    """The state of one pass over a session's messages (the daemon's loop, read side)."""

    def __init__(self, tl: Timeline, mode: str | None, predictions: bool) -> None:
        self.tl = tl
        self.mode = mode
        self.tracker = PairTracker(tl.pair_window)
        self.recent: OrderedDict[int, Perception] = OrderedDict()  # newest perception per tick
        self.last_dropped: int | None = None
        self.want = {keyexpr.key(tl.robot, k): k for k in _KINDS
                     if predictions or k != "prediction"}
        self.drop_topic = dropped_topic(tl.robot)
        self.dx = tl.dims.x if tl.dims else None
        self.dy = tl.dims.y if tl.dims else None

    @property
    def segment(self) -> Segment:
        return self.tl.segments[-1]

    def message(self, lm: LogMessage) -> None:
        """Apply one logged message."""
        tl = self.tl
        kind = self.want.get(lm.topic)
        if kind is None:
            if lm.topic == self.drop_topic:
                _drop(tl, self.segment, lm.message.data)
            return
        tl.messages += 1
        dims = Dims(self.dx, self.dy) if self.dx and self.dy else None
        try:
            msg: Message = decode(kind, lm.message.data, dims=dims, robot=tl.robot)
        except ProtocolError as exc:
            tl.invalid[exc.reason] += 1
            return
        t_ns = lm.message.log_time
        pair = None
        if isinstance(msg, Perception):
            pair = self._perception(msg)
        elif isinstance(msg, Action):
            pair = self._action(msg)
        elif isinstance(msg, Control):
            self._control(msg)
        elif isinstance(msg, Prediction):
            self._prediction(msg, t_ns)
        elif isinstance(msg, Status):
            self._status(msg)
        if pair is not None:
            p, a = pair
            seg = self.segment
            seg.pairs.append(LearnedPair(index=seg.end_updates, tick=p.tick, x=p.x, y=a.y,
                                         label=a.label, log_time_ns=t_ns))

    def _perception(self, msg: Perception) -> tuple[Perception, Action] | None:
        if self.dx is None:
            self.dx = msg.x.size
        elif msg.x.size != self.dx:
            self.tl.invalid["wrong_dimension"] += 1
            return None
        self.recent[msg.tick] = msg
        self.recent.move_to_end(msg.tick)
        if len(self.recent) > 4 * self.tracker.max_pending:
            self.recent.popitem(last=False)
        if self.mode in LEARNING_MODES:
            return self.tracker.perception(msg)
        self.tl.ignored_not_learning += 1
        return None

    def _action(self, msg: Action) -> tuple[Perception, Action] | None:
        if self.dy is None:
            self.dy = msg.y.size
        elif msg.y.size != self.dy:
            self.tl.invalid["wrong_dimension"] += 1
            return None
        if self.mode in LEARNING_MODES:
            return self.tracker.action(msg)
        self.tl.ignored_not_learning += 1
        return None

    def _control(self, msg: Control) -> None:
        if msg.op == "mode":
            self.mode = msg.mode
        elif msg.op == "reset":
            self.tl.segments.append(Segment(start_updates=0, after_reset=True))
            self.tracker = PairTracker(self.tl.pair_window)

    def _prediction(self, msg: Prediction, t_ns: int) -> None:
        q = self.recent.get(msg.tick)
        if q is None:
            self.tl.predictions_without_query += 1
            return
        self.segment.predictions.append(RecordedPrediction(
            tick=msg.tick, updates=msg.updates, x=q.x, mean=msg.mean, var=msg.var,
            expert=msg.expert, multimap=msg.multimap, mode=msg.mode, log_time_ns=t_ns))

    def _status(self, msg: Status) -> None:
        if self.last_dropped is not None and msg.dropped > self.last_dropped:
            self.tl.daemon_dropped += msg.dropped - self.last_dropped
        self.last_dropped = msg.dropped

    def finish(self) -> None:
        """Dims learned from the messages, and what was left unpaired."""
        if self.tl.dims is None and self.dx is not None and self.dy is not None:
            self.tl.dims = Dims(self.dx, self.dy)
        self.tl.unpaired = self.tracker.pending


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


def robot_absent(files: Iterable[Path], robot: str) -> str:
    """Why ``robot`` cannot be replayed from ``files`` ("" if it has messages there).

    The message names the robots the log does have.
    """
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
