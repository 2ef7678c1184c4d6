"""Offline replay: a recorded session fed through the daemon's own ``RobotRuntime``.

``roger replay FILE...`` (:mod:`.cli`) reads a session's timeline
(:func:`roger_daemon.recording.read_timeline`), learns its pairs in the recorded order,
recomputes every recorded prediction and compares (:mod:`.session`, :mod:`.result`); it can
start from a daemon checkpoint and save the replayed model as one (:mod:`.checkpoint`).
:mod:`.compare` owns the tolerance of a cross-machine comparison. docs/durability.md and
docs/reproducibility.md say what "bit-identical" and "within tolerance" mean.
"""

from __future__ import annotations

from roger_daemon.replay.compare import behaviour, behaviour_differences, probe_inputs
from roger_daemon.replay.session import (
    PredictionDiff,
    ReplayError,
    ReplayResult,
    load_checkpoint,
    replay_session,
    replay_timeline,
    resume_timeline,
    save_checkpoint,
)

__all__ = [
    "PredictionDiff",
    "ReplayError",
    "ReplayResult",
    "behaviour",
    "behaviour_differences",
    "load_checkpoint",
    "probe_inputs",
    "replay_session",
    "replay_timeline",
    "resume_timeline",
    "save_checkpoint",
]
