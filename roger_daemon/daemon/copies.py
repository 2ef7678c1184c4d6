"""The other copy of the learned pairs: the session logs' decision records, for start-up.

The write-ahead log is the record of what was learned; the session logs hold the same pairs
(``learned`` decision records, docs/durability.md). When the log lost some (a damaged
record, or segments pruned after a checkpoint that turned out unreadable), start-up takes them
from the session logs (:func:`session_log_copies`, used by ``wal_replay.replay_into``) so that
no acknowledged pair is lost while a copy survives.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from roger_daemon.config import DaemonConfig, RobotConfig
from roger_daemon.daemon.checkpoint import Checkpoint
from roger_daemon.daemon.robot import RobotRuntime
from roger_daemon.daemon.wal_read import WalRecord
from roger_daemon.daemon.wal_replay import Copies

__all__ = ["checkpoint_position", "log_repairs", "session_log_copies"]

log = logging.getLogger(__name__)


def checkpoint_position(rt: RobotRuntime, ckpt: Checkpoint) -> Any:
    """Where ``rt``, as just restored from ``ckpt``, stands in the session logs (a
    ``recording.startup.CheckpointPosition``: learned pairs, session, segment, queue)."""
    from roger_daemon.recording.startup import CheckpointPosition
    from roger_daemon.recording.timeline import LearnedPair

    start = rt.updates
    queue = tuple(LearnedPair(start + i, p.tick, p.x, p.y,
                              rt.vocab[p.label] if 0 <= p.label < len(rt.vocab) else "", 0)
                  for i, p in enumerate(rt.queue))
    return CheckpointPosition(
        learned=start, session_id=ckpt.meta.session_id or "", segment=ckpt.meta.session_segment,
        last_tick=rt.last_learned_tick, queue=queue, path=str(ckpt.path))


def log_repairs(robot: str, plan: Any) -> None:
    """One warning per footer-less session log that a recovery plan repaired in place."""
    for rep in plan.recovered:
        if rep.output:
            log.warning("%s: log %s had no footer (killed daemon): recovered in place, %d "
                        "messages in %d chunks kept, %d bytes of unreadable tail dropped "
                        "(original kept as %s.damaged)", robot, rep.source, rep.messages,
                        rep.chunks, rep.bytes_dropped, Path(rep.source).name)


def session_log_copies(cfg: DaemonConfig, robot: RobotConfig, rt: RobotRuntime,
                       ckpt: Checkpoint | None) -> Copies | None:
    """The pairs learned after ``ckpt`` as the session logs hold them, read on first use
    (only when the write-ahead log lost some); None without recording or checkpoint."""
    if not cfg.recording.enabled or ckpt is None:
        return None
    pos = checkpoint_position(rt, ckpt)
    found: dict[int, Any] = {}
    read = False

    def copies(wanted: range, anchor: WalRecord | None) -> Sequence[WalRecord]:
        nonlocal read
        if not read:
            read = True
            found.update(_read(cfg, robot, rt, pos))
        if anchor is not None and anchor.index in found:
            p = found[anchor.index]
            if p.tick != anchor.tick or anchor.x is None or not np.array_equal(p.x, anchor.x):
                log.warning("%s: the session logs' pair %d (tick %d) is not the write-ahead "
                            "log's (tick %d): another history, not used", rt.robot,
                            anchor.index, p.tick, anchor.tick)
                return []
        out = []
        for i in wanted:
            p = found.get(i)
            if p is None:
                break
            out.append(WalRecord("pair", -1, i, int(p.tick), np.asarray(p.x, dtype=np.float64),
                                 np.asarray(p.y, dtype=np.float64), str(p.label)))
        return out

    return copies


def _read(cfg: DaemonConfig, robot: RobotConfig, rt: RobotRuntime, pos: Any) -> dict[int, Any]:
    from roger_daemon.recording.startup import plan_recovery

    plan = plan_recovery(cfg.recording.dir, robot.id, dims=rt.dims, checkpoint=pos)
    log_repairs(robot.id, plan)
    for note in plan.notes:
        log.warning("%s: reading the session logs for pairs the write-ahead log lost: %s",
                    robot.id, note)
    if plan.fresh:  # the logs restart the history: not the checkpoint's pairs
        return {}
    return {p.index: p for p in (*pos.queue, *plan.pairs)}
