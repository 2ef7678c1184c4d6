"""Where each robot's model starts when the daemon starts.

The newest valid checkpoint (unless ``--fresh``; :func:`load_robot`), then the write-ahead log
after it (``checkpoint.wal``), then start-up self-recovery from the session logs when recording
is on (:func:`recover_from_logs`: footer-less logs recovered, the pairs logged after the
checkpoint re-learned unless the write-ahead log already restored them, a ``recovered``
checkpoint written). :func:`start_robots` does all three for every configured robot.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from protocols.messages import Dims
from roger_daemon.config import DaemonConfig, RobotConfig
from roger_daemon.daemon.checkpoint import (
    Checkpoint,
    CheckpointError,
    CheckpointMeta,
    list_checkpoints,
    load_newest,
    write_checkpoint,
)
from roger_daemon.daemon.checkpoint_meta import LearnerSpec
from roger_daemon.daemon.copies import checkpoint_position, log_repairs, session_log_copies
from roger_daemon.daemon.robot import RobotRuntime
from roger_daemon.daemon.robot_state import RobotState
from roger_daemon.daemon.sdnotify import Notifier
from roger_daemon.daemon.service import checkpoint_snapshot

__all__ = [
    "Resumed",
    "build_robot",
    "load_robot",
    "make_model",
    "model_meta",
    "recover_from_logs",
    "start_robots",
]

log = logging.getLogger(__name__)

#: ``info.recovery`` in status is a protocol string (at most 256 characters)
MAX_RECOVERY_CHARS = 256


def make_model(robot: RobotConfig) -> Any:
    """A fresh model for ``robot``: its ``model`` kind from the one registry
    (:func:`roger_daemon.config.models.build_model`: the paper's ROGER, the unimap baseline,
    or ROGER with its transitions learned online)."""
    from roger_daemon.config.models import build_model

    return build_model(robot.model, robot.x_dim, robot.y_dim, robot.params, robot.seed)


def model_meta(robot: RobotConfig) -> LearnerSpec:
    """Which learner ``robot``'s model is (kind, seed, parameters), as checkpoints record it."""
    return LearnerSpec(robot.model, robot.seed, robot.params.to_mapping())


def build_robot(cfg: DaemonConfig, robot: RobotConfig, *, fresh: bool) -> tuple[RobotRuntime, str]:
    """The runtime of one robot, resumed from its newest valid checkpoint unless ``fresh``."""
    rt, ckpt = load_robot(cfg, robot, fresh=fresh)
    return rt, "" if ckpt is None else str(ckpt.path)


def load_robot(
    cfg: DaemonConfig, robot: RobotConfig, *, fresh: bool
) -> tuple[RobotRuntime, Checkpoint | None]:
    """The runtime of one robot and the checkpoint it resumed from (None: fresh model)."""
    from roger_daemon.config.models import load_model

    if cfg.learner_workers == "inline":  # the loop learns: its compiled kernels now, not in
        from roger_daemon.learner.engine.jit import warm_up  # the robot's first live update

        warm_up()
    # With learner workers each worker warms up its own (worker.py); the loop's process then
    # loads numba only if it re-learns pairs at start-up (recovery), on first use. Loaded
    # here for nothing it held ~124 MB (numba and the kernels), ~312 MB when it compiled them
    # on a cold cache (docs/fleet.md, *Benchmarks*).
    dims = Dims(robot.x_dim, robot.y_dim)
    loaded: dict[str, Any] = {}

    def accept(ck: Checkpoint) -> None:
        if (ck.meta.x_dim, ck.meta.y_dim) != (robot.x_dim, robot.y_dim):
            raise CheckpointError(
                f"dimensions {ck.meta.x_dim}/{ck.meta.y_dim} do not match the "
                f"config's {robot.x_dim}/{robot.y_dim}"
            )
        try:
            loaded["model"] = load_model(ck.model)
        except Exception as exc:  # the learner rejects a state it cannot continue from
            raise CheckpointError(f"the learner cannot load its model state ({exc})") from None
        try:
            state = RobotState.from_arrays(ck.daemon)
        except (KeyError, ValueError) as exc:  # missing, or arrays that do not fit together
            raise CheckpointError(str(exc)) from None
        if int(loaded["model"].n_learned) != state.n_learned:
            raise CheckpointError("model and label counts disagree")

    rt = RobotRuntime(robot.id, dims, None, lambda: make_model(robot), mode=cfg.mode,
                      queue_size=cfg.queue_size, pair_window=cfg.pair_window,
                      learner=model_meta(robot))
    ckpt = None if fresh else load_newest(cfg.checkpoint.dir, robot.id, accept)
    skipped = _skipped(cfg, robot, ckpt) if not fresh else 0
    if skipped:  # said in status (info.recovery) as well as by load_newest's warnings
        rt.recovery = f"{skipped} newer checkpoints unreadable"
    if ckpt is None:
        rt.model = make_model(robot)
        return rt, None
    rt.model = loaded["model"]
    rt.restore(ckpt.daemon, ckpt.meta.counters)
    saved = ckpt.meta.learner.params
    if saved is not None and saved != robot.params.to_mapping():
        log.warning("%s: the checkpoint's learner parameters differ from the config's; "
                    "continuing with the checkpoint's (use --fresh to start over with the "
                    "config's)", robot.id)
    log.info("%s: resumed from %s (%d updates, %d queued pairs, model %s)", robot.id, ckpt.path,
             rt.updates, len(rt.queue), ckpt.meta.model_digest[:12])
    return rt, ckpt


def _skipped(cfg: DaemonConfig, robot: RobotConfig, ckpt: Checkpoint | None) -> int:
    """How many checkpoints newer than ``ckpt`` (all of them if None) were unusable."""
    paths = list_checkpoints(cfg.checkpoint.dir, robot.id)
    return paths.index(ckpt.path) if ckpt is not None and ckpt.path in paths else len(paths)


@dataclass
class Resumed:
    """Where one robot's model stands in the history when its new session starts."""

    checkpoint: str = ""  # the checkpoint file it resumed from ("" for a fresh model)
    session: str | None = None  # that checkpoint's session ("" if it names none)
    segment: int = 0
    recovered_pairs: int = 0
    recovered_from: tuple[str, ...] = ()


def _position(ckpt: Checkpoint | None) -> Resumed:
    if ckpt is None:
        return Resumed("", "", 0)
    return Resumed(str(ckpt.path), ckpt.meta.session_id, ckpt.meta.session_segment)


def _same_learner(robot: RobotConfig, info: Any) -> str:
    """Why a logged fresh model differs from the config's ("" if it does not)."""
    mine = json.loads(json.dumps(robot.params.to_mapping(), sort_keys=True))
    if info.learner_params is not None and info.learner_params != mine:
        return "its learner parameters differ from the config's"
    if info.seed is not None and info.seed != robot.seed:
        return f"its seed {info.seed} is not the config's {robot.seed}"
    if info.model != robot.model:
        return f"its model {info.model!r} is not the config's {robot.model!r}"
    return ""


def recover_from_logs(
    cfg: DaemonConfig, robot: RobotConfig, rt: RobotRuntime, ckpt: Checkpoint | None,
    *, notifier: Notifier | None = None, relearn: bool = True,
) -> tuple[RobotRuntime, Resumed]:
    """Start-up self-recovery of one robot, before its new session opens.

    Recovers footer-less session logs, re-learns the pairs logged after the checkpoint's last
    learned pair (after its queued pairs; see ``roger_daemon.recording.startup``), writes a
    checkpoint (reason ``recovered``) and returns the runtime with where its model now stands.
    Never raises: a bad log is reported and the checkpoint stands as it is.
    With ``relearn=False`` (the write-ahead log already restored what was learned) only the
    logs are repaired and checked.
    """
    from roger_daemon.recording.startup import plan_recovery

    where = _position(ckpt)
    pos = None if ckpt is None else checkpoint_position(rt, ckpt)
    plan = plan_recovery(cfg.recording.dir, robot.id, dims=rt.dims, checkpoint=pos)
    log_repairs(robot.id, plan)
    for note in plan.notes:
        log.warning("%s: start-up recovery: %s", robot.id, note)
    if not plan.newer or not relearn:
        log.info("%s: start-up recovery: %s%s", robot.id, plan.summary,
                 "" if relearn else " (not re-learned: the write-ahead log is the record of "
                 "what was learned)")
        return rt, where
    if plan.fresh:
        why = _same_learner(robot, plan.fresh_info) if plan.fresh_info is not None else ""
        if why:
            log.warning("%s: start-up recovery: the logs restart from a fresh model (%s) but "
                        "%s; logs not used", robot.id, plan.summary, why)
            return rt, where
    if notifier is not None:
        notifier.status(f"recovering {robot.id}: re-learning {len(plan.pairs)} pairs from the "
                        "session logs")
    base = ("a fresh model" if plan.fresh else
            f"checkpoint {where.checkpoint} ({rt.updates} updates, {len(rt.queue)} queued pairs)")
    try:
        if plan.fresh:
            rt.reset()
        for p in plan.pairs:
            rt.enqueue_recovered(p.x, p.y, p.label, p.tick)
        while rt.queue:
            rt.learn_one()
    except Exception:
        log.exception("%s: start-up recovery failed while re-learning; continuing from the "
                      "checkpoint alone", robot.id)
        again, ck2 = load_robot(cfg, robot, fresh=ckpt is None)
        return again, _position(ck2)
    rt.session_resets = 0
    rt.recovered_pairs = len(plan.pairs)
    rt.last_tick = max(rt.last_tick, plan.last_tick or 0)
    files = sorted({Path(f).name for f in plan.files})
    first = plan.pairs[0].tick if plan.pairs else "-"
    log.warning("%s: start-up recovery: %s; re-learned %d pairs (ticks %s..%s) from %s on top "
                "of %s: now %d updates, %d experts", robot.id, plan.summary, len(plan.pairs),
                first, plan.last_tick if plan.pairs else "-", ", ".join(files) or "(no files)",
                base, rt.updates, int(rt.model.n_experts))
    session, segment = plan.position
    try:
        path, full = _write_recovered(cfg, rt, session, segment, len(plan.pairs),
                                      plan.sessions)
    except Exception as exc:
        log.error("%s: could not write the recovered checkpoint (%s); the new session "
                  "records that it resumed from %s plus %d recovered pairs", robot.id, exc,
                  where.checkpoint or "a fresh model", len(plan.pairs))
        return rt, Resumed(where.checkpoint, session, segment, len(plan.pairs),
                           tuple(plan.sessions))
    log.info("%s: checkpoint %s written (recovered, %d updates, model %s)", robot.id, path,
             rt.updates, full.model_digest[:12])
    return rt, Resumed(str(path), session, segment, len(plan.pairs), tuple(plan.sessions))


def start_robots(
    cfg: DaemonConfig, *, fresh: bool, notifier: Notifier | None = None
) -> tuple[dict[str, RobotRuntime], dict[str, Resumed]]:
    """Every robot's runtime: newest checkpoint (unless ``fresh``), then the write-ahead log
    after it (``checkpoint.wal``), then start-up recovery from the session logs (when
    recording is on and not ``fresh``; re-learning from them only without the write-ahead
    log)."""
    robots: dict[str, RobotRuntime] = {}
    where: dict[str, Resumed] = {}
    if not cfg.checkpoint.wal:  # kept on purpose: docs/durability.md, *Without the log*
        log.warning("checkpoint.wal = false: a crash can lose acknowledged pairs; start-up "
                    "re-learns only what the session logs recorded (docs/durability.md)")
    for robot in cfg.robots:
        robots[robot.id], ckpt = load_robot(cfg, robot, fresh=fresh)
        where[robot.id] = _position(ckpt)
        by_wal = False
        if cfg.checkpoint.wal:
            by_wal, where[robot.id] = _start_wal(cfg, robot, robots[robot.id], ckpt,
                                                 fresh=fresh)
        if cfg.recording.enabled and not fresh:
            # Before the new session opens: an open session would cut the history it reads.
            robots[robot.id], logs = recover_from_logs(
                cfg, robot, robots[robot.id], ckpt, notifier=notifier, relearn=not by_wal)
            if not by_wal:
                where[robot.id] = logs
    return robots, where


def _start_wal(cfg: DaemonConfig, robot: RobotConfig, rt: RobotRuntime,
               ckpt: Checkpoint | None, *, fresh: bool) -> tuple[bool, Resumed]:
    """Replay the write-ahead log after the checkpoint and attach it to ``rt``.

    Returns whether the log is the authority on what was learned (then the session logs are
    not re-learned) and where the model now stands (the ``recovered`` checkpoint written
    after a replay, which the new session names as its start). Pairs the log lost are taken
    from the session logs when they hold them (:mod:`roger_daemon.daemon.copies`).
    """
    from roger_daemon.daemon import wal

    d = wal.wal_dir(cfg.checkpoint.dir, rt.robot)
    seq = None if ckpt is None else ckpt.meta.wal_seq
    has_log = bool(wal.read_records(d)) if seq is None else True
    copies = None if fresh else session_log_copies(cfg, robot, rt, ckpt)
    rep = wal.start(rt, d, checkpoint_seq=seq,
                    replay=has_log and not fresh,
                    fresh=fresh or (ckpt is None and not has_log), copies=copies,
                    preallocate=cfg.checkpoint.wal_reserve_kb << 10)
    _report(rt, d, ckpt, rep)
    where = _position(ckpt)
    if rep.pairs or rep.fresh or rep.stopped or rep.copied or rep.lost:  # durable at once
        try:
            path, _ = _write_recovered(cfg, rt, where.session or "", where.segment,
                                       rep.pairs + rep.copied)
            log.info("%s: checkpoint %s written (recovered, %d updates)", rt.robot, path,
                     rt.updates)
            where = Resumed(str(path), where.session, where.segment, rep.pairs + rep.copied)
        except OSError as exc:
            log.error("%s: could not write the recovered checkpoint (%s); the write-ahead "
                      "log still holds the pairs", rt.robot, exc)
    return has_log and not fresh, where


def _report(rt: RobotRuntime, d: Path, ckpt: Checkpoint | None, rep: Any) -> None:
    """Log what the write-ahead log's replay found and did; ``rt.recovery`` says it in
    status (docs/durability.md, *Torn and corrupt records*)."""
    for dmg in rep.damage:
        if dmg.torn_tail:
            log.warning("%s: write-ahead log %s", rt.robot, dmg.describe())
        else:
            log.error("%s: write-ahead log %s", rt.robot, dmg.describe())
    for note in rep.notes:
        log.error("%s: write-ahead log %s: %s", rt.robot, d, note)
    if rep.stopped:
        log.error("%s: write-ahead log %s: %s", rt.robot, d, rep.stopped)
    rt.recovered_pairs = rep.pairs + rep.copied
    rt.recovery_lost = rep.lost
    if rep.pairs or rep.fresh or rep.copied:
        log.warning("%s: start-up recovery: re-learned %d pairs (ticks %s..%s) and %d resets "
                    "from the write-ahead log %s and %d pairs from the session logs after %s: "
                    "now %d updates", rt.robot, rep.pairs, rep.first_tick, rep.last_tick,
                    rep.fresh, d, rep.copied,
                    ckpt.path if ckpt is not None else "a fresh model", rt.updates)
    parts = [f"checkpoint {Path(str(ckpt.path)).name} ({ckpt.meta.updates} updates)"
             if ckpt is not None else "a fresh model"]
    if rt.recovery:  # what load_robot found (checkpoints skipped)
        parts[0] += f", {rt.recovery}"
    if rep.pairs or rep.fresh:
        parts.append(f"{rep.pairs} pairs and {rep.fresh} resets from the write-ahead log")
    if rep.copied:
        parts.append(f"{rep.copied} pairs from the session logs")
    if rep.lost:
        parts.append(f"{rep.lost} pairs lost (no intact copy)")
    bad = [dm for dm in rep.damage if not dm.torn_tail]
    if bad:
        parts.append(f"{len(bad)} damaged stretches of the log skipped "
                     f"(first: {bad[0].describe()})")
    rt.recovery = " + ".join(parts)[:MAX_RECOVERY_CHARS]


def _write_recovered(cfg: DaemonConfig, rt: RobotRuntime, session: str, segment: int,
                     pairs: int, sessions: Sequence[str] = ()) -> tuple[Path, CheckpointMeta]:
    """Write ``rt`` as a checkpoint of reason ``recovered`` standing at ``session``/``segment``
    after re-learning ``pairs`` pairs (from the session logs of ``sessions``)."""
    model, daemon, meta = checkpoint_snapshot(
        rt, "recovered", daemon_id=cfg.id, created_unix_ns=time.time_ns(), session_id=session,
        session_segment=segment, recovered_pairs=pairs, recovered_from=sessions)
    return write_checkpoint(cfg.checkpoint.dir, rt.robot, model, daemon, meta,
                            **cfg.checkpoint.limits())
