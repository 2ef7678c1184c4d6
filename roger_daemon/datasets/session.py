"""Pairs into a session log the daemon's tools can learn from: what ``roger log import`` writes.

The log is a version-2 session (``roger-session/2``, :mod:`roger_daemon.recording.metadata`)
as a daemon would have recorded it, one robot, ticks in order:

* per pair, ``perception(t)`` and ``action(t)`` (with its label, and its ``source`` where the
  protocol carries one), then the daemon's decision record ``learned`` (the pair as model
  pair ``i``), so that ``roger replay LOG --save-checkpoint DIR`` rebuilds the model a daemon
  learning these pairs would have (and the daemon resumes from it), and ``roger replay LOG
  --publish`` feeds the pairs to a live daemon;
* ``episode`` events ``start`` / ``end`` around each episode;
* the metadata: the robot, its profile (names, ranges), dims, fps (``rate_hz``), the learner
  parameters, seed and model the pairs are to be learned with.

Log times are ``start_ns + index / fps`` (the pairs' own time line); the publish times the
same.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path
from typing import Any

from protocols import Action, EpisodeEvent, Perception, encode, keys
from protocols.decisions import Learned
from roger_daemon.datasets.pairs import Pairs

__all__ = ["write_session"]


def _with_source(cls: type, source: str, **kw: Any) -> Any:
    """``cls(**kw)`` with ``source`` if the message has that field (the protocol's action and
    learned record carry who gave the action where the version has it)."""
    if source and "source" in {f.name for f in dataclasses.fields(cls)}:
        kw["source"] = source
    return cls(**kw)


def write_session(pairs: Pairs, directory: str | Path, *, params: Any, seed: int = 0,
                  model: str = "roger", created_by: str = "roger log import",
                  source_name: str = "", start_ns: int | None = None) -> Path:
    """Write ``pairs`` as one session file in ``directory``; return its path."""
    from roger_daemon.recording.metadata import session_metadata
    from roger_daemon.recording.writer import SessionRecorder

    if not len(pairs):
        raise ValueError("no pairs to write")
    robot = keys.validate_robot_id(pairs.robot)
    t0 = time.time_ns() if start_ns is None else int(start_ns)
    meta = session_metadata(
        robot=robot, learner_params=params, dims=pairs.profile.dims, seed=seed, model=model,
        created_by=created_by, decisions=True,
        extra={"rate_hz": repr(float(pairs.fps)), "clock": "lockstep",
               "robot_profile": json.dumps(pairs.profile.to_mapping()),
               "imported_from": source_name, "task": pairs.task})
    rec = SessionRecorder(directory, robot=robot, metadata=meta, rotate_bytes=None,
                          rotate_s=None, start_ns=t0)
    ok = False
    try:
        frame = pairs.frame_index()
        for i in range(len(pairs)):
            tick, ep = int(pairs.tick[i]), int(pairs.episode[i])
            t = float(frame[i] / pairs.fps)
            ns = t0 + round(i * 1e9 / pairs.fps)
            msgs: list[tuple[str, Any]] = []
            if frame[i] == 0:
                msgs.append((keys.episode(robot), EpisodeEvent(robot, tick, t, event="start",
                                                               episode=ep, stamp_ns=ns)))
            msgs += [
                (keys.perception(robot), Perception(robot, tick, t, x=pairs.x[i], stamp_ns=ns)),
                (keys.action(robot), _with_source(
                    Action, pairs.source[i], robot=robot, tick=tick, t=t, y=pairs.y[i],
                    label=pairs.label[i], stamp_ns=ns)),
                (keys.decision(robot, "learned"), _with_source(
                    Learned, pairs.source[i], robot=robot, tick=tick, t=t, updates=i + 1,
                    segment=0, x=pairs.x[i], y=pairs.y[i], label=pairs.label[i],
                    stamp_ns=ns)),
            ]
            if i + 1 == len(pairs) or pairs.episode[i + 1] != ep:
                msgs.append((keys.episode(robot), EpisodeEvent(robot, tick, t, event="end",
                                                               episode=ep, stamp_ns=ns)))
            for key, msg in msgs:
                rec.write(key, encode(msg), log_time_ns=ns, publish_time_ns=ns, sequence=tick)
        ok = True
    finally:
        rec.close()
        if not ok:
            for p in rec.paths:
                p.unlink(missing_ok=True)
    return rec.path
