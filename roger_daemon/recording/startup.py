"""Start-up self-recovery: is there a session log newer than the checkpoint, and what to re-learn.

The daemon calls :func:`plan_recovery` for each robot after it has loaded its newest checkpoint
and before it opens the new session's recorder (an open session would cut the history):

1. footer-less session files (a killed daemon) are recovered in place
   (:func:`~roger_daemon.recording.recover.recover_directory`; the damaged bytes stay as
   ``X.mcap.damaged``);
2. the history is walked from the checkpoint's session and segment (checkpoint metadata
   ``session_id``/``session_segment``; :func:`~roger_daemon.recording.catchup.log_tail`), and
   the pairs learned after the checkpoint's last pair are returned, after its queued pairs;
3. without any checkpoint, the newest session is re-learned from a fresh model if it started
   fresh and ended in a crash (no footer): the daemon was killed before its first checkpoint.

It never raises for a bad log: a corrupt file, a log of another history, a tick that does not
match, a gap all end up in :attr:`RecoveryPlan.notes` and the plan re-learns nothing (or only
the part that is certain). Applying the plan is the daemon's job (its runtime holds labels
and counters): learn :attr:`RecoveryPlan.pairs` after the restored queue (on a fresh model when
:attr:`RecoveryPlan.fresh`), write a checkpoint at :attr:`RecoveryPlan.position`, then open the
new session.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from protocols.messages import Dims
from roger_daemon.recording import files as sfiles
from roger_daemon.recording.catchup import (
    CatchUpError,
    _assemble,
    _result,
    _walk,
)
from roger_daemon.recording.metadata import SessionInfo
from roger_daemon.recording.recover import RecoverReport, recover_directory
from roger_daemon.recording.timeline import LearnedPair

__all__ = ["CheckpointPosition", "RecoveryPlan", "plan_recovery"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class CheckpointPosition:
    """What the daemon restored: where its checkpoint stands in the history.

    ``session_id``/``segment``/``last_tick`` come from the checkpoint's metadata
    (``session_id``, ``session_segment``, ``counters.last_learned_tick``); ``queue`` holds its
    queued pairs (index ``learned``, ``learned + 1``, ...).
    """

    learned: int
    session_id: str = ""
    segment: int = 0
    last_tick: int | None = None
    queue: tuple[LearnedPair, ...] = ()
    path: str = ""


@dataclass
class RecoveryPlan:
    """What :func:`plan_recovery` found and what to re-learn."""

    robot: str
    recovered: list[RecoverReport] = field(default_factory=list)
    #: pairs to learn after the checkpoint's queue (or, if ``fresh``, on a fresh model)
    pairs: list[LearnedPair] = field(default_factory=list)
    fresh: bool = False
    #: the session whose fresh model the pairs start from (its params, seed and model kind)
    fresh_info: SessionInfo | None = None
    #: (session id, segment) where the history stands after the pairs
    position: tuple[str, int] = ("", 0)
    sessions: list[str] = field(default_factory=list)
    files: list[Path] = field(default_factory=list)
    #: warnings: logs skipped or not used, and why
    notes: list[str] = field(default_factory=list)
    #: one line: what was decided
    summary: str = ""

    @property
    def newer(self) -> bool:
        """The logs hold pairs the checkpoint does not (something to re-learn)."""
        return bool(self.pairs) or self.fresh

    @property
    def last_tick(self) -> int | None:
        """Tick of the last pair to re-learn."""
        return self.pairs[-1].tick if self.pairs else None


def _recover_files(plan: RecoveryPlan, log_dir: Path, robot: str) -> set[str]:
    """Recover footer-less files; return the ids of the sessions that had one (crashed)."""
    crashed: set[str] = set()
    try:
        reports = recover_directory(log_dir, robot=robot)
    except Exception as exc:  # e.g. the directory cannot be listed
        plan.notes.append(f"could not check the logs in {log_dir} for missing footers ({exc})")
        return crashed
    for rep in reports:
        plan.recovered.append(rep)
        sf = sfiles.parse_name(rep.source)
        if sf is not None:
            crashed.add(sf.session_id)
        if not rep.output:
            plan.notes.append(f"log {rep.source} is not usable: {rep.error}")
    return crashed


def plan_recovery(
    log_dir: str | Path,
    robot: str,
    *,
    dims: Dims | None,
    checkpoint: CheckpointPosition | None,
    recover_files: bool = True,
) -> RecoveryPlan:
    """What to re-learn from the logs of ``robot`` in ``log_dir`` on top of ``checkpoint``.

    ``checkpoint`` is None when the daemon found no usable checkpoint (fresh model). Never
    raises for bad logs (see the module doc); an unexpected error is caught, noted, and the
    plan re-learns nothing.
    """
    plan = RecoveryPlan(robot=robot)
    d = Path(log_dir)
    if not d.is_dir():
        plan.summary = f"no log directory {d}"
        return plan
    try:
        crashed = _recover_files(plan, d, robot) if recover_files else set()
        _plan(plan, d, robot, dims, checkpoint, crashed)
    except Exception as exc:  # a bug or an odd file: never stop the daemon's start-up
        log.debug("recovery planning failed", exc_info=True)
        plan.pairs, plan.fresh, plan.fresh_info = [], False, None
        plan.notes.append(f"reading the logs failed ({type(exc).__name__}: {exc}); logs not used")
        plan.summary = "logs not used (error)"
    return plan


def _locate_checkpoint(plan: RecoveryPlan, sessions: list[list[Path]], ids: list[str],
                       ck: CheckpointPosition
                       ) -> tuple[int, int, tuple[int, tuple[str, int]] | None] | None:
    """Which session log (index), segment and start position continue the checkpoint; ``None``
    (with ``plan.summary`` saying why) if no log does."""
    start: tuple[int, tuple[str, int]] | None = None
    first = -1
    segment = ck.segment
    if ck.session_id and ck.session_id in ids:
        first = ids.index(ck.session_id)
    elif ck.session_id:
        # The checkpoint's own log is gone: sessions started after it may still continue it.
        key = sfiles.session_order(ck.session_id)
        later = [i for i, s in enumerate(ids)
                 if key is not None and (sfiles.session_order(s) or key) > key]
        if not later:
            plan.summary = f"the checkpoint's session {ck.session_id} is not among the logs"
            return None
        first, start = later[0], (ck.learned, (ck.session_id, ck.segment))
        plan.notes.append(f"the checkpoint's session {ck.session_id} is not among the logs; "
                          "reading the sessions after it")
    else:
        # A checkpoint that does not name its session (recording was off, or an older daemon):
        # only a session that says it resumed from this very file continues it.
        for i, parts in enumerate(sessions):
            info = _info(parts[0])
            if (info is not None and ck.path and info.checkpoint == ck.path
                    and info.start_updates == ck.learned):
                first, segment = i, 0
        if first < 0:
            plan.summary = "the checkpoint does not name its session and no log resumed from it"
            return None
    return first, segment, start


def _plan(plan: RecoveryPlan, d: Path, robot: str, dims: Dims | None,
          ck: CheckpointPosition | None, crashed: set[str]) -> None:
    sessions = sfiles.sessions(d, robot)
    if not sessions:
        plan.summary = "no session logs"
        return
    ids = [sfiles.session_id_of(parts[0]) for parts in sessions]
    if ck is None:
        _plan_without_checkpoint(plan, sessions, ids, robot, dims, crashed)
        return
    located = _locate_checkpoint(plan, sessions, ids, ck)
    if located is None:
        return
    first, segment, start = located
    w = _walk(sessions, first, segment=segment, robot=robot, dims=dims, start=start,
              check_dims=True)
    plan.notes.extend(w.notes)
    plan.sessions = w.sessions
    if not w.started:
        plan.summary = (f"segment {segment} of the checkpoint's session {ids[first]} is not in "
                        "its log")
        return
    try:
        pairs, missing = _assemble(w, learned=ck.learned, last_tick=ck.last_tick,
                                   queue=ck.queue)
    except CatchUpError as exc:
        if exc.reason == "behind" and not w.fresh:
            plan.summary = ("the checkpoint is newer than the logs (the crash lost the last "
                            "flush interval of log): nothing to re-learn")
        else:
            plan.notes.append(f"the logs do not continue the checkpoint: {exc}; logs not used")
            plan.summary = "logs not used (they do not continue the checkpoint)"
        return
    res = _result(w, pairs, missing, ck.learned)
    plan.notes.extend(res.notes[len(w.notes):])
    if w.unexplained_drops:
        plan.notes.append(f"the logs show {w.unexplained_drops} pairs dropped (queue full) "
                          "without drop records: the re-learned model may differ")
    if res.fresh:
        if not pairs and not w.fresh_by_reset:
            plan.summary = (f"a later session ({res.position[0]}) started fresh but learned "
                            "nothing: keeping the checkpoint")
            return
        plan.fresh, plan.fresh_info = True, res.fresh_info
        plan.pairs = list(pairs)
    else:
        plan.pairs = list(pairs[len(ck.queue):])
    plan.position = res.position
    plan.files = list(res.files)
    if plan.fresh:
        plan.summary = (f"the history restarted from a fresh model after the checkpoint "
                        f"(reset or fresh session, {res.position[0]}): {len(plan.pairs)} pairs "
                        "to re-learn from a fresh model")
    elif plan.pairs:
        plan.summary = (f"{len(plan.pairs)} pairs in the logs after the checkpoint's "
                        f"{ck.learned} updates" + (f" and {len(ck.queue)} queued pairs"
                                                  if ck.queue else ""))
    else:
        plan.summary = "the logs hold nothing newer than the checkpoint"


def _info(path: Path) -> SessionInfo | None:
    from roger_daemon.recording.mcapio import read_metadata

    try:
        return SessionInfo.from_metadata(read_metadata(path))
    except Exception:
        return None


def _plan_without_checkpoint(plan: RecoveryPlan, sessions: Sequence[list[Path]],
                             ids: list[str], robot: str, dims: Dims | None,
                             crashed: set[str]) -> None:
    """No checkpoint: re-learn the newest session if it started fresh and crashed."""
    last = len(sessions) - 1
    info = _info(sessions[last][0])
    was_damaged = ids[last] in crashed or any(
        p.with_name(p.name + ".damaged").exists() for p in sessions[last])
    if info is None or not info.fresh or not was_damaged:
        plan.summary = ("no checkpoint, and the newest log did not start fresh and crash: "
                        "nothing to re-learn")
        return
    w = _walk(list(sessions), last, segment=0, robot=robot, dims=dims, check_dims=True)
    plan.notes.extend(w.notes)
    if not w.started:
        plan.summary = f"no checkpoint, and the newest log ({ids[last]}) cannot be read"
        return
    # The walk started inside the session: its history starts from a fresh model.
    w.fresh = True
    w.fresh_info = w.fresh_info or info
    pairs, missing = _assemble(w, learned=0, last_tick=None, queue=())
    res = _result(w, pairs, missing, 0)
    plan.notes.extend(res.notes[len(w.notes):])
    if not pairs:
        plan.summary = f"no checkpoint, and the newest log ({ids[last]}) holds no learned pair"
        return
    plan.fresh, plan.fresh_info = True, res.fresh_info
    plan.pairs = list(pairs)
    plan.position = res.position
    plan.sessions = res.sessions
    plan.files = list(res.files)
    plan.summary = (f"no checkpoint; the newest session {ids[last]} started fresh and crashed: "
                    f"{len(pairs)} pairs to re-learn from a fresh model")
