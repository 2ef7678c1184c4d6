"""Read a recorded session into a :class:`~roger_daemon.recording.timeline.Timeline`.

:func:`read_timeline` walks the messages of a session's files in write order. What every log
needs is here (:class:`Reading`: decoding, each prediction's query perception, dims, the
status' drop counter); where the learned pairs come from depends on the log's format version
(:mod:`roger_daemon.recording.timeline`): the daemon's decision records for version 2
(:class:`DecisionReading`), re-pairing the recorded inputs for version 1
(:class:`~roger_daemon.recording.read_inputs.InputsReading`).
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Iterable
from pathlib import Path

from protocols import keys as keyexpr
from protocols.decisions import (
    Dropped,
    Learned,
    ModelDigest,
    Reset,
    chain_digest,
    decode_decision,
)
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
from roger_daemon.daemon.pairing import DEFAULT_PAIR_WINDOW
from roger_daemon.recording.mcapio import LogMessage, LogReader, read_metadata, topics_of
from roger_daemon.recording.metadata import SessionInfo
from roger_daemon.recording.timeline import (
    LearnedPair,
    ModelCheck,
    RecordedPrediction,
    Segment,
    Timeline,
)

__all__ = ["DecisionReading", "Reading", "read_timeline", "robot_absent"]

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
    perception and action; ``mode`` matters to version-1 logs only). ``predictions=False``
    skips the recorded predictions (log-tail catch-up needs only the pairs; predictions are the
    costliest messages to decode).
    """
    from roger_daemon.recording.read_inputs import InputsReading

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
    queued = info.restored_queued_pairs if start_updates is None and not info.decisions else 0
    tl = Timeline(info=info, robot=_robot_for(info, topics, robot), dims=dims or info.dims,
                  segments=[Segment(start_updates=start, after_reset=False, queued=queued)],
                  files=files, file_errors={}, incomplete_files=[], decisions=info.decisions)
    tl.pair_window = info.pair_window or DEFAULT_PAIR_WINDOW
    reading: Reading = (DecisionReading(tl, predictions) if info.decisions
                        else InputsReading(tl, mode or info.mode, predictions))
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


class Reading:
    """One pass over a session's messages: what every format version reads the same way.

    Subclasses say where the learned pairs come from: :meth:`perception`, :meth:`action`,
    :meth:`control` and :meth:`decision` (a record on ``roger/<robot>/daemon/<event>``).
    """

    def __init__(self, tl: Timeline, predictions: bool) -> None:
        self.tl = tl
        self.recent: OrderedDict[int, Perception] = OrderedDict()  # newest perception per tick
        self.last_dropped: int | None = None
        self.want = {keyexpr.key(tl.robot, k): k for k in _KINDS
                     if predictions or k != "prediction"}
        self.events = {keyexpr.decision(tl.robot, e): e for e in keyexpr.DECISIONS}
        self.dx = tl.dims.x if tl.dims else None
        self.dy = tl.dims.y if tl.dims else None

    @property
    def segment(self) -> Segment:
        """The segment being read (the last one)."""
        return self.tl.segments[-1]

    def message(self, lm: LogMessage) -> None:
        """Apply one logged message."""
        tl = self.tl
        kind = self.want.get(lm.topic)
        if kind is None:
            event = self.events.get(lm.topic)
            if event is not None:
                self.decision(event, lm)
            return
        tl.messages += 1
        dims = Dims(self.dx, self.dy) if self.dx and self.dy else None
        try:
            msg: Message = decode(kind, lm.message.data, dims=dims, robot=tl.robot)
        except ProtocolError as exc:
            tl.invalid[exc.reason] += 1
            return
        t_ns = lm.message.log_time
        if isinstance(msg, Perception):
            self._perception(msg, t_ns)
        elif isinstance(msg, Action):
            self._action(msg, t_ns)
        elif isinstance(msg, Control):
            self.control(msg)
        elif isinstance(msg, Prediction):
            self._prediction(msg, t_ns)
        elif isinstance(msg, Status):
            self._status(msg)

    def _perception(self, msg: Perception, t_ns: int) -> None:
        if self.dx is None:
            self.dx = msg.x.size
        elif msg.x.size != self.dx:
            self.tl.invalid["wrong_dimension"] += 1
            return
        self.recent[msg.tick] = msg
        self.recent.move_to_end(msg.tick)
        if len(self.recent) > 4 * self.tl.pair_window:
            self.recent.popitem(last=False)
        self.perception(msg, t_ns)

    def _action(self, msg: Action, t_ns: int) -> None:
        if self.dy is None:
            self.dy = msg.y.size
        elif msg.y.size != self.dy:
            self.tl.invalid["wrong_dimension"] += 1
            return
        self.action(msg, t_ns)

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

    # --- where the learned pairs come from ------------------------------------------------

    def perception(self, msg: Perception, t_ns: int) -> None:
        """A valid perception of the robot (after the checks every reader makes)."""

    def action(self, msg: Action, t_ns: int) -> None:
        """A valid action of the robot."""

    def control(self, msg: Control) -> None:
        """A control message the daemon received."""

    def decision(self, event: str, lm: LogMessage) -> None:
        """A decision record of the robot (``event``: one of ``protocols.keys.DECISIONS``)."""

    def finish(self) -> None:
        """After the last message: dims learned from the messages."""
        if self.tl.dims is None and self.dx is not None and self.dy is not None:
            self.tl.dims = Dims(self.dx, self.dy)


class DecisionReading(Reading):
    """Version 2: the learned pairs, resets and model digests are the daemon's own records.

    :attr:`Timeline.unpaired` counts the perceptions and actions of ticks that no decision
    record names (never learned nor dropped); nothing else is derived from the inputs.
    """

    def __init__(self, tl: Timeline, predictions: bool) -> None:
        super().__init__(tl, predictions)
        self.input_ticks: tuple[set[int], set[int]] = (set(), set())
        self.named: set[int] = set()
        self.chain = tl.info.raw.get("start_model_digest", "")  # as the records so far make it

    def perception(self, msg: Perception, t_ns: int) -> None:
        """Noted, to count the ticks no decision names."""
        self.input_ticks[0].add(msg.tick)

    def action(self, msg: Action, t_ns: int) -> None:
        """Noted, to count the ticks no decision names."""
        self.input_ticks[1].add(msg.tick)

    def decision(self, event: str, lm: LogMessage) -> None:
        """Apply one decision record (an undecodable one is counted as invalid)."""
        tl = self.tl
        try:
            rec = decode_decision(event, lm.message.data, dims=tl.dims, robot=tl.robot)
        except ProtocolError as exc:
            tl.invalid[exc.reason] += 1
            return
        if isinstance(rec, Learned):
            seg = self.segment
            if rec.updates - 1 != seg.end_updates:
                tl.invalid["decision_gap"] += 1  # a record missing in between: not expected
            seg.pairs.append(LearnedPair(index=rec.updates - 1, tick=rec.tick, x=rec.x, y=rec.y,
                                         label=rec.label, log_time_ns=lm.message.log_time))
            self.named.add(rec.tick)
        elif isinstance(rec, Reset):
            tl.segments.append(Segment(start_updates=0, after_reset=True))
        elif isinstance(rec, Dropped):
            tl.dropped_recorded += 1
            self.named.add(rec.tick)
        elif isinstance(rec, ModelDigest):
            self.chain = chain_digest(self.chain, rec.digest)
            if rec.chain != self.chain:  # a model record is missing or altered
                tl.invalid["digest_chain"] += 1
                self.chain = rec.chain
            if rec.segment < len(tl.segments):
                tl.segments[rec.segment].digests.append(ModelCheck(rec.updates, rec.digest,
                                                                   rec.chain))

    def finish(self) -> None:
        """Dims, and the inputs no decision names."""
        super().finish()
        perceptions, actions = self.input_ticks
        self.tl.unpaired = (len(perceptions - self.named), len(actions - self.named))


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
