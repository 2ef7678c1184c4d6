"""Session recording to MCAP, log tools, offline replay and log-tail catch-up.

The daemon's seam::

    from roger_daemon.recording import SessionRecorder, session_metadata

    meta = session_metadata(robot="aibo", config_text=text, learner_params=params,
                            dims=DIMS, seed=seed, mode=mode, start_updates=model.n_learned)
    rec = SessionRecorder(log_dir, robot="aibo", metadata=meta)      # flush_interval_s=1.0
    rec.write(key, payload, log_time_ns=t_recv, publish_time_ns=msg.stamp_ns, sequence=msg.tick)
    rec.poll(time.monotonic_ns())     # every loop cycle: flushes/rotates when due, else ~free
    rec.close()                       # on shutdown: summary, indexes, footer, fsync

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
