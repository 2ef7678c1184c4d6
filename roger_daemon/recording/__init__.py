"""Session recording to MCAP, log tools, offline replay and log-tail catch-up.

The daemon's seam::

    from roger_daemon.recording import SessionRecorder, session_metadata

    meta = session_metadata(robot="aibo", config_text=text, learner_params=params,
                            dims=DIMS, seed=seed, mode=mode, start_updates=model.n_learned,
                            pair_window=cfg.pair_window, queue_size=cfg.queue_size)
    rec = SessionRecorder(log_dir, robot="aibo", metadata=meta)      # flush_interval_s=1.0
    rec.write(key, payload, log_time_ns=t_recv, publish_time_ns=msg.stamp_ns, sequence=msg.tick)
    rec.poll(time.monotonic_ns())     # every loop cycle: flushes/rotates when due, else ~free
    rec.close()                       # on shutdown: summary, indexes, footer, fsync

Start-up self-recovery after a crash (phase 2), before opening the new recorder::

    recover_directory(log_dir)                               # footer-less files -> indexed
    ck = <newest checkpoint>: model (n_learned U) + queued pairs Q
    tail = log_tail(log_dir, learned=U, robot=r, from_session=ck.meta.get("session_id"))
    for p in tail.after_queue(Q.ticks): enqueue(p)           # the logged pairs after Q
    # learn Q + tail, write a checkpoint, then start the session with
    # session_metadata(..., start_updates=model.n_learned, checkpoint=<that file>)

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
from roger_daemon.recording.replay import (
    PredictionDiff,
    ReplayError,
    ReplayResult,
    replay_session,
    replay_timeline,
)
from roger_daemon.recording.schemas import schema, schema_bytes, schema_name
from roger_daemon.recording.timeline import (
    LearnedPair,
    PairTracker,
    RecordedPrediction,
    Timeline,
    read_timeline,
)
from roger_daemon.recording.writer import RecorderStats, SessionRecorder, header_fields

__all__ = [
    "METADATA_NAME",
    "CatchUp",
    "CatchUpError",
    "LearnedPair",
    "LogMessage",
    "LogReader",
    "PairTracker",
    "PredictionDiff",
    "RecordedPrediction",
    "RecorderStats",
    "RecoverReport",
    "ReplayError",
    "ReplayResult",
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
    "read_metadata",
    "read_timeline",
    "recover",
    "recover_directory",
    "recover_in_place",
    "replay_session",
    "replay_timeline",
    "schema",
    "schema_bytes",
    "schema_name",
    "session_metadata",
]
