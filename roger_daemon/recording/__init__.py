"""Session recording to MCAP, log tools and log-tail catch-up (replay: roger_daemon.replay).

The daemon's seam::

    from roger_daemon.recording import SessionRecorder, session_metadata

    meta = session_metadata(robot="aibo", config_text=text, learner_params=params,
                            dims=DIMS, seed=seed, mode=mode, start_updates=model.n_learned,
                            pair_window=cfg.pair_window, queue_size=cfg.queue_size)
    rec = SessionRecorder(log_dir, robot="aibo", metadata=meta)      # flush_interval_s=1.0
    rec.write(key, payload, log_time_ns=t_recv, publish_time_ns=msg.stamp_ns, sequence=msg.tick)
    rec.poll(time.monotonic_ns())     # every loop cycle: flushes/rotates when due, else ~free
    rec.close()                       # on shutdown: summary, indexes, footer, fsync

Start-up self-recovery after a crash (``roger_daemon.daemon.recover_from_logs``), before the
new recorder opens (an open session would cut the history)::

    pos = CheckpointPosition(learned=U, session_id=ck.meta.session_id,
                             segment=ck.meta.session_segment,
                             last_tick=ck.meta.counters.last_learned_tick, queue=Q)
    plan = plan_recovery(log_dir, robot, dims=DIMS, checkpoint=pos)   # never raises
    # plan.recovered: footer-less files made whole; plan.notes: logs skipped and why
    # learn Q, then plan.pairs (on a fresh model if plan.fresh), write a checkpoint at
    # plan.position, then start the session with session_metadata(..., start_updates=
    # model.n_learned, checkpoint=<that file>, resumed_session=..., resumed_segment=...)

By hand: ``roger log recover FILE --in-place``, then ``roger replay FILE --checkpoint CK
--save-checkpoint DIR`` (:func:`roger_daemon.replay.resume_timeline`,
:func:`roger_daemon.replay.save_checkpoint`).

The daemon's decisions are in the log too (format version 2: a record per learned pair,
reset, dropped pair and checkpoint digest on ``roger/<robot>/daemon/<event>``,
:mod:`protocols.decisions`): replay and recovery read the learned pairs from them. Version-1
logs (older daemons, ``roger record``) are read by re-pairing their inputs with the daemon's
own rule (:mod:`.read_inputs`).

Nothing here imports Zenoh (only ``cli_record``, ``zenoh_net`` and ``publish`` do).
"""

from __future__ import annotations

from roger_daemon.recording.catchup import CatchUp, CatchUpError, log_tail
from roger_daemon.recording.files import SessionFile, list_session_files, parse_name
from roger_daemon.recording.mcapio import LogMessage, LogReader, is_complete, read_metadata
from roger_daemon.recording.metadata import (
    METADATA_NAME,
    SessionInfo,
    package_versions,
    session_metadata,
)
from roger_daemon.recording.recover import (
    RecoverReport,
    recover,
    recover_directory,
    recover_in_place,
)
from roger_daemon.recording.schemas import schema, schema_bytes, schema_name
from roger_daemon.recording.session_read import read_timeline
from roger_daemon.recording.startup import CheckpointPosition, RecoveryPlan, plan_recovery
from roger_daemon.recording.timeline import LearnedPair, RecordedPrediction, Timeline
from roger_daemon.recording.writer import RecorderStats, SessionRecorder, header_fields

__all__ = [
    "METADATA_NAME",
    "CatchUp",
    "CatchUpError",
    "CheckpointPosition",
    "LearnedPair",
    "LogMessage",
    "LogReader",
    "RecordedPrediction",
    "RecorderStats",
    "RecoverReport",
    "RecoveryPlan",
    "SessionFile",
    "SessionInfo",
    "SessionRecorder",
    "Timeline",
    "header_fields",
    "is_complete",
    "list_session_files",
    "log_tail",
    "package_versions",
    "parse_name",
    "plan_recovery",
    "read_metadata",
    "read_timeline",
    "recover",
    "recover_directory",
    "recover_in_place",
    "schema",
    "schema_bytes",
    "schema_name",
    "session_metadata",
]
