"""A hot standby catching up with the daemon that serves a robot (docs/daemon.md, *Hot
standby*): the serving daemon's state as its files hold it, handed over Zenoh.

The serving daemon answers a query on ``roger/@daemon/<id>/sync/<robot>`` with what its own
start-up recovery would resume from (docs/durability.md, *Start-up*): its newest valid
checkpoint file, byte for byte, and the records of its write-ahead log after that checkpoint's
``wal_seq``, as decision records (``learned`` with ``updates`` = the record's index + 1,
``reset`` for a fresh model). It reads only files (immutable checkpoints, an append-only log),
so it runs on Zenoh's thread and never touches the loop's model.

The standby replaces its model and daemon state by the checkpoint's, writes a checkpoint of
its own at once (its write-ahead log then starts from that state: a kill right after leaves
a consistent disk), and queues the records' pairs like any decided pairs. Live records that
arrived meanwhile are applied after them; the ones the reply already held are recognised by
their ``updates``.
"""

from __future__ import annotations

import json
import logging
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import msgpack

from protocols.decisions import Learned, Reset, decode_decision
from protocols.message_types import Message, encode
from protocols.packing import packb
from roger_daemon.config import DaemonConfig
from roger_daemon.daemon.checkpoint import CheckpointError, load_newest, read_checkpoint
from roger_daemon.daemon.robot import RobotRuntime
from roger_daemon.daemon.robot_state import RobotState
from roger_daemon.daemon.wal import read_records, wal_dir

__all__ = ["SyncError", "history", "install"]

log = logging.getLogger(__name__)


class SyncError(Exception):
    """The serving daemon's state could not be handed over (the reason is the message)."""


def history(cfg: DaemonConfig, robot: str) -> bytes:
    """The answer to a standby's sync query for ``robot`` (module doc), as one msgpack map:
    ``daemon``, ``checkpoint`` (the file's bytes, empty without one), ``records``
    (``[event, payload]`` each) or ``error``."""
    c = cfg.checkpoint
    try:
        if not c.wal:
            raise SyncError(f"daemon {cfg.id} runs without a write-ahead log (checkpoint.wal)")
        ck = load_newest(c.dir, robot)
        after = -1 if ck is None or ck.meta.wal_seq is None else ck.meta.wal_seq
        data = b"" if ck is None or ck.path is None else ck.path.read_bytes()
        records: list[list[Any]] = []
        for rec in read_records(wal_dir(c.dir, robot), after_seq=after):
            if rec.kind == "fresh":
                records.append(["reset", encode(Reset(robot, 0, 0.0, segment=0, forgotten=0))])
            elif rec.x is not None and rec.y is not None:
                records.append(["learned", encode(Learned(
                    robot, rec.tick, 0.0, updates=rec.index + 1, segment=0, x=rec.x, y=rec.y,
                    label=rec.label))])
        return packb({"daemon": cfg.id, "checkpoint": data, "records": records, "error": ""})
    except (OSError, SyncError) as exc:  # a segment pruned while read, no log: said, retried
        return packb({"daemon": cfg.id, "checkpoint": b"", "records": [], "error": str(exc)})


def _canonical(params: Mapping[str, Any] | None) -> str:
    """Parameters as compared (a checkpoint's come back from JSON: lists for tuples)."""
    return json.dumps(None if params is None else dict(params), sort_keys=True, default=str)


def install(rt: RobotRuntime, payload: bytes, directory: Path) -> tuple[str, list[Message]]:
    """Replace ``rt``'s model and state by the answer ``payload`` (its checkpoint, or a fresh
    model without one); return the serving daemon's id and the records to follow after it.

    ``directory``: where the checkpoint file is put while it is read (the robot's checkpoint
    directory: the same disk). ``SyncError`` if the answer is an error or does not fit.
    """
    try:
        m = msgpack.unpackb(payload, raw=False)
        daemon, data, raw_records = str(m["daemon"]), bytes(m["checkpoint"]), list(m["records"])
        error = str(m.get("error", ""))
    except Exception as exc:
        raise SyncError(f"not a sync answer ({type(exc).__name__}: {exc})") from None
    if error:
        raise SyncError(error)
    records = []
    for event, body in raw_records:
        records.append(decode_decision(str(event), bytes(body), dims=rt.dims, robot=rt.robot))
    if not data:
        rt.reset()  # the serving daemon has no checkpoint: its log starts with a fresh model
        return daemon, records
    from roger_daemon.config.models import load_model

    directory.mkdir(parents=True, exist_ok=True)
    with tempfile.NamedTemporaryFile(dir=directory, prefix=".sync-", suffix=".npz") as f:
        f.write(data)
        f.flush()
        try:
            ck = read_checkpoint(Path(f.name))
        except CheckpointError as exc:
            raise SyncError(f"its checkpoint does not read ({exc})") from None
    if (ck.meta.x_dim, ck.meta.y_dim) != (rt.dims.x, rt.dims.y):
        raise SyncError(f"its checkpoint is of dimensions {ck.meta.x_dim}/{ck.meta.y_dim}, "
                        f"not {rt.dims.x}/{rt.dims.y}")
    try:
        model = load_model(ck.model)
        RobotState.from_arrays(ck.daemon)
    except Exception as exc:
        raise SyncError(f"its checkpoint does not load ({exc})") from None
    theirs, ours = ck.meta.learner, rt.learner
    if (theirs.kind, theirs.seed, _canonical(theirs.params)) != (
            ours.kind, ours.seed, _canonical(ours.params)):
        raise SyncError("its learner (kind, seed, parameters) differs from ours: give both "
                        "daemons the same [learner], [[robots]] and seed")
    rt.model = model
    rt.restore(ck.daemon, ck.meta.counters)
    rt.queue.clear()  # the pairs it had queued come as records, once learned
    rt.generation += 1
    return daemon, records
