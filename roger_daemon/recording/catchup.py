"""Log-tail catch-up: the pairs learned after a checkpoint, read back from the session logs.

After a crash the daemon restores its last checkpoint (a model that had learned ``learned``
pairs, the last of them at tick ``last_tick``, plus its queue of formed but unlearned pairs) and
re-learns :attr:`CatchUp.pairs` in order; the result equals the model of the same session run
without the crash, as long as the logs hold every pair (a SIGKILL loses at most the last flush
interval of log; those pairs are lost for good and :attr:`CatchUp.pairs` simply ends earlier).

**The history** is rebuilt by walking the sessions of one robot in order, segment by segment
(a segment is a session's start, or the stretch after a ``reset`` control):

* the walk starts in the checkpoint's session and segment (``from_session``/``segment``, kept in
  the daemon's checkpoint metadata), or, without them, in the last session whose
  ``start_updates`` is <= ``learned``;
* a later session that resumed from a checkpoint of this history (its metadata
  ``resumed_session``/``resumed_segment``; logs without those keys: ``start_updates`` within
  the history) continues it at its ``start_updates``: the checkpoint's queued pairs
  (``restored_queued_pairs``) come next, then its own pairs; anything the history held after
  that point was never learned by the model that went on, so it is dropped;
* a ``reset``, or a session that started from a fresh model, starts a *fresh* history: then the
  checkpoint is obsolete and :attr:`CatchUp.fresh` says to re-learn the pairs from a fresh model;
* a session that resumed from a checkpoint of another history ends the walk (reported in
  :attr:`CatchUp.notes`; what came before it is still used).

Pairs the logs lack (the crash lost the last flush interval) but the checkpoint's queue holds
are taken from the queue (pass ``queue``); any other hole ends :attr:`CatchUp.pairs` there
(:attr:`CatchUp.missing_from`). Footer-less files are read up to their last complete chunk (no
need to recover them first, though the daemon does, so that the files become indexed).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from protocols.messages import Dims
from roger_daemon.recording import files as sfiles
from roger_daemon.recording.mcapio import read_metadata
from roger_daemon.recording.metadata import SessionInfo
from roger_daemon.recording.session_read import read_timeline
from roger_daemon.recording.timeline import LearnedPair

__all__ = ["CatchUp", "CatchUpError", "log_tail"]


class CatchUpError(RuntimeError):
    """The logs do not continue the checkpoint (gap, other history, or wrong tick).

    ``reason`` is one of ``"no_logs"``, ``"missing_session"``, ``"gap"`` (the logs start after
    the checkpoint), ``"behind"`` (the logs end before it), ``"mismatch"`` (a tick differs: the
    checkpoint belongs to another history).
    """

    def __init__(self, message: str, reason: str = "mismatch") -> None:
        super().__init__(message)
        self.reason = reason


@dataclass(frozen=True)
class CatchUp:
    """What to re-learn on top of a checkpoint (or, if :attr:`fresh`, from a fresh model)."""

    pairs: list[LearnedPair]  # in order; pairs[0].index == learned (0 if fresh)
    learned: int  # the checkpoint's n_learned
    sessions: list[str]  # session ids read
    files: list[Path]
    incomplete_files: list[str] = field(default_factory=list)
    file_errors: dict[str, str] = field(default_factory=dict)
    #: the history restarted from a fresh model after the checkpoint (reset, fresh session)
    fresh: bool = False
    #: the session (its metadata) whose fresh model the pairs start from, when ``fresh``
    fresh_info: SessionInfo | None = None
    #: (session id, segment) of the last segment walked: where the history now stands
    position: tuple[str, int] = ("", 0)
    #: first index the logs lack (pairs stop before it), None if nothing is missing
    missing_from: int | None = None
    #: pairs the daemon dropped (queue full) that no drop record names: replay is not exact
    unexplained_drops: int = 0
    #: what the walk skipped or where it stopped, and why
    notes: list[str] = field(default_factory=list)

    @property
    def start(self) -> int:
        """``n_learned`` of the model the pairs are learned on (0 if fresh)."""
        return 0 if self.fresh else self.learned

    @property
    def final_updates(self) -> int:
        """``n_learned`` after re-learning every pair."""
        return self.start + len(self.pairs)

    @property
    def last_tick(self) -> int | None:
        """Tick of the last pair to re-learn (None if nothing to re-learn)."""
        return self.pairs[-1].tick if self.pairs else None

    def after_queue(self, queue_ticks: Sequence[int]) -> list[LearnedPair]:
        """The pairs that follow a checkpoint's restored training queue.

        A daemon checkpoint holds the model (``learned`` pairs) and its queue of pairs formed
        but not yet learned: the first pairs of the log tail. Keep the restored queue, check
        that it agrees with the log, and enqueue what this returns after it. (If the log ends
        inside the queue, because the crash lost the last flush interval, nothing is returned
        and the queue alone is right.) A fresh history discards the queue: everything is
        returned.
        """
        if self.fresh:
            return list(self.pairs)
        n = min(len(queue_ticks), len(self.pairs))
        logged = [p.tick for p in self.pairs[:n]]
        if [int(t) for t in queue_ticks[:n]] != logged:
            raise CatchUpError(
                f"the checkpoint's queued ticks {list(queue_ticks[:n])[:5]}... differ from the "
                f"log's {logged[:5]}..."
            )
        return self.pairs[len(queue_ticks):]


@dataclass
class _Walk:
    """The history as the walk rebuilds it: ``history[i]`` has index ``base + i``; None marks
    a pair the logs lack."""

    base: int
    history: list[LearnedPair | None]
    fresh: bool = False
    fresh_info: SessionInfo | None = None
    position: tuple[str, int] = ("", 0)
    lineage: set[tuple[str, int]] = field(default_factory=set)
    sessions: list[str] = field(default_factory=list)
    files: list[Path] = field(default_factory=list)
    incomplete: list[str] = field(default_factory=list)
    errors: dict[str, str] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    unexplained_drops: int = 0
    started: bool = False
    fresh_by_reset: bool = False

    @property
    def end(self) -> int:
        return self.base + len(self.history)

    def restart(self, info: SessionInfo, pos: tuple[str, int], *, reset: bool) -> None:
        """A fresh model from here on (reset or fresh session)."""
        self.base, self.history, self.fresh, self.fresh_info = 0, [], True, info
        self.fresh_by_reset = reset
        self.lineage = {pos}

    def resume_at(self, index: int) -> bool:
        """The next pairs continue the history at ``index``; False if that is impossible."""
        if index < self.base:
            return False
        if index <= self.end:
            del self.history[index - self.base:]
        else:
            self.history.extend([None] * (index - self.end))
        return True


def _walk(
    sessions: list[list[Path]],
    first: int,
    *,
    segment: int,
    robot: str | None,
    dims: Dims | None,
    start: tuple[int, tuple[str, int]] | None = None,
    check_dims: bool = False,
) -> _Walk:
    """Walk ``sessions[first:]``; see the module doc.

    ``start`` = (index, position): begin with an empty history at that index, in that lineage
    position (the checkpoint's session is not among the logs); otherwise the walk begins in
    ``sessions[first]`` at ``segment``.
    """
    w = _Walk(base=0, history=[])
    if start is not None:
        w.base, w.position = start[0], start[1]
        w.lineage = {start[1]}
        w.started = True
    for i in range(first, len(sessions)):
        if not w.started and i > first:
            break  # the checkpoint's session or segment is not in the logs
        parts = sessions[i]
        sid = sfiles.session_id_of(parts[0])
        try:
            tl = read_timeline(parts, robot=robot, dims=dims, predictions=False)
        except Exception as exc:  # unreadable or unrelated file: report, go on without it
            w.notes.append(f"session {sid} skipped: cannot read it ({exc})")
            for p in parts:
                w.errors[str(p)] = str(exc)
            continue
        logged = tl.info.dims
        if check_dims and dims is not None and logged is not None and logged != dims:
            w.notes.append(f"session {sid} skipped: dimensions {logged.x}/{logged.y} are not "
                           f"the robot's {dims.x}/{dims.y}")
            continue
        info = tl.info
        w.sessions.append(sid)
        w.files.extend(parts)
        w.incomplete.extend(tl.incomplete_files)
        w.errors.update(tl.file_errors)
        w.unexplained_drops += tl.unexplained_drops
        for j, seg in enumerate(tl.segments):
            pos = (sid, j)
            if not w.started:
                if j < segment:
                    continue
                w.started = True
                w.base, w.history = seg.first_index, []
                w.lineage = {pos}
            elif seg.after_reset:
                w.restart(info, pos, reset=True)
            elif j == 0 and info.fresh:
                w.restart(info, pos, reset=False)
            else:
                parent = (info.resumed_session or "", info.resumed_segment)
                if info.resumed_session and parent not in w.lineage:
                    w.notes.append(
                        f"session {sid} resumed from a checkpoint of another history "
                        f"(session {parent[0]}, segment {parent[1]}); it and later sessions "
                        "are not used")
                    return w
                if not info.resumed_session and not w.base <= seg.start_updates <= w.end:
                    w.notes.append(
                        f"session {sid} resumed at update {seg.start_updates}, outside this "
                        f"history ({w.base}..{w.end}); it and later sessions are not used")
                    return w
                if not w.resume_at(seg.first_index):
                    w.notes.append(
                        f"session {sid} resumed at update {seg.start_updates}, before this "
                        f"history's start ({w.base}); it and later sessions are not used")
                    return w
                w.lineage.add(pos)
            w.history.extend(seg.pairs)
            w.position = pos
    return w


def _assemble(
    w: _Walk,
    *,
    learned: int,
    last_tick: int | None,
    queue: Sequence[LearnedPair],
) -> tuple[list[LearnedPair], int | None]:
    """The pairs from ``learned`` on (or from 0 if fresh), holes filled from the queue.

    Returns (pairs, first missing index or None). Raises :class:`CatchUpError` when the logs
    contradict the checkpoint or do not reach it.
    """
    def at(i: int) -> LearnedPair | None:
        return w.history[i - w.base] if w.base <= i < w.end else None

    if w.fresh:
        out: list[LearnedPair] = []
        for i in range(w.base, w.end):
            p = at(i)
            if p is None:
                return out, i
            out.append(p)
        return out, None
    qticks = [q.tick for q in queue]
    if learned < w.base and w.base - learned > len(queue):
        raise CatchUpError(
            f"the logs start at update {w.base}, after the checkpoint's {learned}: pairs are "
            "missing", "gap")
    if learned > w.end:
        raise CatchUpError(
            f"the checkpoint has {learned} updates but the logs end at {w.end}: the checkpoint "
            "is newer than the logs, or belongs to another history", "behind")
    prev = at(learned - 1)
    if last_tick is not None and learned > 0 and prev is not None and prev.tick != last_tick:
        raise CatchUpError(
            f"update {learned} in the logs is tick {prev.tick}, the checkpoint says tick "
            f"{last_tick}")
    for k, t in enumerate(qticks):
        p = at(learned + k)
        if p is not None and p.tick != t:
            raise CatchUpError(
                f"the checkpoint's queued ticks {qticks[:5]}... differ from the log's (update "
                f"{learned + k}: tick {p.tick}, queue: tick {t})")
    out = []
    for i in range(learned, max(w.end, learned + len(queue))):
        p = at(i)
        if p is None and i - learned < len(queue):
            p = queue[i - learned]
        if p is None:
            return out, i
        out.append(p)
    return out, None


def log_tail(
    source: str | Path | Iterable[str | Path],
    *,
    learned: int,
    robot: str | None = None,
    last_tick: int | None = None,
    dims: Dims | None = None,
    from_session: str | None = None,
    segment: int = 0,
    queue: Sequence[LearnedPair] = (),
) -> CatchUp:
    """The pairs learned after a checkpoint that had learned ``learned`` pairs.

    Parameters
    ----------
    source
        A log directory (every session of ``robot`` in it, oldest first) or the files (parts of
        one or more sessions; recognised session names are ordered by name, others kept in the
        order given).
    learned
        The checkpoint's ``n_learned``.
    robot
        The robot (required for a directory with several robots' logs).
    last_tick
        The tick of the checkpoint's last learned pair, if known: checked against the log, to
        catch a checkpoint that belongs to another history.
    dims
        Perception/action sizes if the metadata lacks them.
    from_session, segment
        The session the checkpoint was taken in (``SessionRecorder.session_id``, stored in the
        daemon's checkpoint metadata) and the segment (resets before it in that session):
        start reading there. Default: the last session whose ``start_updates`` is <=
        ``learned``, from its first segment.
    queue
        The checkpoint's queued pairs (indices ``learned``, ``learned + 1``, ...): checked
        against the log and used where the log lacks them. ``pairs`` include them.

    Raises
    ------
    CatchUpError
        If the logs start after the checkpoint (a gap), end before it, disagree on its tick, or
        do not hold ``from_session``.
    """
    sessions = sfiles.sessions(source, robot)
    if not sessions:
        raise CatchUpError(f"no session logs in {source}", "no_logs")
    first = 0
    if from_session is not None:
        ids = [sfiles.session_id_of(parts[0]) for parts in sessions]
        if from_session not in ids:
            raise CatchUpError(
                f"session {from_session} is not among the logs ({len(ids)} found)",
                "missing_session")
        first = ids.index(from_session)
    else:
        # Only sessions from the last one that started at or before the checkpoint matter.
        for i, parts in enumerate(sessions):
            try:
                su = int(read_metadata(parts[0]).get("start_updates", "") or 0)
            except Exception:
                continue
            if su <= learned:
                first = i
    w = _walk(sessions, first, segment=segment, robot=robot, dims=dims)
    if not w.started:
        raise CatchUpError(
            f"the logs hold no segment {segment} of session {from_session or '?'}", "gap")
    pairs, missing = _assemble(w, learned=learned, last_tick=last_tick, queue=queue)
    return _result(w, pairs, missing, learned)


def _result(w: _Walk, pairs: list[LearnedPair], missing: int | None, learned: int) -> CatchUp:
    notes = list(w.notes)
    if missing is not None:
        notes.append(f"the logs lack the pair of update {missing}; the "
                     f"{max(0, w.end - missing - 1)} pairs logged after it cannot be used")
    return CatchUp(
        pairs=pairs,
        learned=learned,
        sessions=w.sessions,
        files=w.files,
        incomplete_files=w.incomplete,
        file_errors=w.errors,
        fresh=w.fresh,
        fresh_info=w.fresh_info,
        position=w.position,
        missing_from=missing,
        unexplained_drops=w.unexplained_drops,
        notes=notes,
    )
