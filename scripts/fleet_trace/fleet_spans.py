"""What ``scripts/fleet_trace.py`` times in a daemon and its learner workers: the loop's work
besides answering and the answers themselves (docs/fleet.md, *Status one robot at a time*).

Each span is ``(module, attribute path, label)``; the wrapped callable records ``(label, robot,
tick, start ns, end ns)`` on the machine's monotonic clock. ``tests/test_fleet_trace.py``
checks that every path still resolves, so a rename cannot silently empty a trace.
"""

from __future__ import annotations

#: spans of the daemon's loop process
DAEMON = (
    ("roger_daemon.daemon.service.loop", "Service.step", "step"),
    ("roger_daemon.daemon.service.loop", "Service._commit_all", "commit_all"),
    ("roger_daemon.daemon.service.status", "StatusPublisher.robot_status", "status_robot"),
    ("roger_daemon.daemon.service.status", "StatusPublisher.publish", "status"),
    ("roger_daemon.daemon.service.recording", "Recorders.write_held", "recording_writes"),
    ("roger_daemon.recording.writer", "SessionRecorder.flush", "recorder_flush"),
    ("roger_daemon.daemon.service.checkpoints", "Checkpoints.write", "checkpoint_take"),
    ("roger_daemon.daemon.service.checkpoints", "Checkpoints._done", "checkpoint_book"),
    ("roger_daemon.daemon.service.checkpoints", "write_checkpoint", "checkpoint_file"),
    ("roger_daemon.daemon.wal", "WriteAheadLog.commit", "wal_commit"),
    ("roger_daemon.daemon.service.loop", "collect_when_idle", "loop_collection"),
)

#: spans of a learner worker (``python -m roger_daemon.daemon.worker``: its ``__main__``)
WORKER = (
    ("__main__", "_Worker.idle", "worker_labels"),
)
