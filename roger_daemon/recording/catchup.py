"""Log-tail catch-up: the pairs learned after a checkpoint, read back from the session logs.

After a crash the daemon restores its last checkpoint (a model that had learned ``learned``
pairs, the last of them at tick ``last_tick``) and re-learns :attr:`CatchUp.pairs` in order; the
result equals the model of the same session run without the crash, as long as the logs hold
every pair (a SIGKILL loses at most the last flush interval of log; those pairs are lost for
good and :attr:`CatchUp.pairs` simply ends earlier).

The history is rebuilt across sessions: each session's first segment starts at its metadata's
``start_updates`` (the checkpoint count it resumed from), so a later session that resumed from an
older checkpoint overrides the tail of the earlier one; a ``reset`` control message restarts the
history at 0. Footer-less files are read up to their last complete chunk (no need to recover
them first, though the daemon should, so the files become indexed).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from protocols.messages import Dims
from roger_daemon.recording import files as sfiles
from roger_daemon.recording.mcapio import read_metadata
from roger_daemon.recording.timeline import LearnedPair, read_timeline

__all__ = ["CatchUp", "CatchUpError", "log_tail"]


class CatchUpError(RuntimeError):
    """The logs do not continue the checkpoint (gap, other history, or wrong tick)."""


@dataclass(frozen=True)
class CatchUp:
    """What to re-learn on top of a checkpoint."""

    pairs: list[LearnedPair]  # in order; pairs[0].index == learned
    learned: int  # the checkpoint's n_learned
    sessions: list[str]  # session ids read
    files: list[Path]
    incomplete_files: list[str] = field(default_factory=list)
    file_errors: dict[str, str] = field(default_factory=dict)

    @property
    def final_updates(self) -> int:
        """``n_learned`` after re-learning every pair."""
        return self.learned + len(self.pairs)

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
        and the queue alone is right.)
        """
        n = min(len(queue_ticks), len(self.pairs))
        logged = [p.tick for p in self.pairs[:n]]
        if [int(t) for t in queue_ticks[:n]] != logged:
            raise CatchUpError(
                f"the checkpoint's queued ticks {list(queue_ticks[:n])[:5]}... differ from the "
                f"log's {logged[:5]}..."
            )
        return self.pairs[len(queue_ticks):]


def _sessions(source: str | Path | Iterable[str | Path], robot: str | None) -> list[list[Path]]:
    if isinstance(source, str | Path) and Path(source).is_dir():
        found = sfiles.list_session_files(source, robot=robot)
        return [[sf.path for sf in g] for g in sfiles.group_sessions(found)]
    paths = [Path(source)] if isinstance(source, str | Path) else [Path(p) for p in source]
    parsed = [sfiles.parse_name(p) for p in paths]
    if all(sf is not None for sf in parsed):
        return [[sf.path for sf in g] for g in sfiles.group_sessions(
            [sf for sf in parsed if sf is not None])]
    # Unnamed files: group by the session id in their metadata, keeping the given order.
    groups: dict[str, list[Path]] = {}
    for p in paths:
        sid = read_metadata(p).get("session_id", "") or str(p)
        groups.setdefault(sid, []).append(p)
    return list(groups.values())


def _session_id(path: Path) -> str:
    sf = sfiles.parse_name(path)
    return sf.session_id if sf is not None else read_metadata(path).get("session_id", str(path))


def log_tail(
    source: str | Path | Iterable[str | Path],
    *,
    learned: int,
    robot: str | None = None,
    last_tick: int | None = None,
    dims: Dims | None = None,
    from_session: str | None = None,
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
    from_session
        The session the checkpoint was taken in (``SessionRecorder.session_id``, e.g. stored in
        the checkpoint's metadata): start reading there. Default: the last session whose
        ``start_updates`` is <= ``learned``.

    Raises
    ------
    CatchUpError
        If the logs start after the checkpoint (a gap), end before it, or disagree on its tick.
    """
    sessions = _sessions(source, robot)
    if not sessions:
        raise CatchUpError(f"no session logs in {source}")
    first = 0
    if from_session is not None:
        ids = [_session_id(parts[0]) for parts in sessions]
        if from_session not in ids:
            raise CatchUpError(f"session {from_session} is not among the logs ({len(ids)} found)")
        first = ids.index(from_session)
    else:
        # Only sessions from the last one that started at or before the checkpoint matter.
        for i, parts in enumerate(sessions):
            if int(read_metadata(parts[0]).get("start_updates", "") or 0) <= learned:
                first = i
    base = None
    history: list[LearnedPair] = []
    used: list[Path] = []
    incomplete: list[str] = []
    errors: dict[str, str] = {}
    for parts in sessions[first:]:
        tl = read_timeline(parts, robot=robot, dims=dims)
        used.extend(parts)
        incomplete.extend(tl.incomplete_files)
        errors.update(tl.file_errors)
        for seg in tl.segments:
            s = seg.start_updates
            if base is None or seg.after_reset or s < base or s > base + len(history):
                base, history = s, []
            else:
                del history[s - base:]
            history.extend(seg.pairs)
    assert base is not None
    end = base + len(history)
    if learned < base:
        raise CatchUpError(
            f"the logs start at update {base}, after the checkpoint's {learned}: pairs are missing"
        )
    if learned > end:
        raise CatchUpError(
            f"the checkpoint has {learned} updates but the logs end at {end}: the checkpoint is "
            "newer than the logs, or belongs to another history"
        )
    if last_tick is not None and learned > base and history[learned - 1 - base].tick != last_tick:
        raise CatchUpError(
            f"update {learned} in the logs is tick {history[learned - 1 - base].tick}, the "
            f"checkpoint says tick {last_tick}"
        )
    return CatchUp(
        pairs=history[learned - base:],
        learned=learned,
        sessions=[_session_id(p[0]) for p in sessions[first:]],
        files=used,
        incomplete_files=incomplete,
        file_errors=errors,
    )
