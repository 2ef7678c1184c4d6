"""Recorded sessions for the replay and recovery tests, made by the daemon's own code.

:func:`record_session` drives the real daemon in process: its configuration parser, its model
loader (``roger_daemon.daemon.resume.load_robot``, a real checkpoint when one is given), its
recorders (``roger_daemon.daemon.open_recorders``, the real ``SessionRecorder``) and its
service loop (``Service``, lockstep clock) on the in-memory transport with a fake 30 Hz clock.
The daemon writes the log, decision records included; the returned object holds what the daemon
did (the pairs it learned, the predictions it published), which a correct replay reproduces.

:func:`as_version_1` copies a log as a daemon that did not record its decisions would have
written it (format ``roger-session/1``, no ``learned``/``reset``/``model`` records), so that
the version-1 reader is tested on the same sessions.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from mcap_testing import copy_log

from protocols import Action, Control, Perception, Prediction, decode, encode, keys
from protocols.messages import Dims
from roger_daemon.config import parse_config
from roger_daemon.daemon.checkpoint import list_checkpoints, read_checkpoint, write_checkpoint
from roger_daemon.daemon.checkpoint_meta import CheckpointMeta, Counters
from roger_daemon.daemon.learners import ProcessLearners
from roger_daemon.daemon.main import open_recorders
from roger_daemon.daemon.resume import Resumed, load_robot, start_robots
from roger_daemon.daemon.robot import Pair, RobotRuntime
from roger_daemon.daemon.robot_state import RobotState
from roger_daemon.daemon.service import Service
from roger_daemon.daemon.service.recording import DecisionLog
from roger_daemon.recording import METADATA_NAME
from roger_daemon.recording.metadata import FORMAT_INPUTS_ONLY
from roger_daemon.testing import MemoryTransport

__all__ = [
    "START_NS",
    "DaemonSession",
    "as_version_1",
    "daemon_checkpoint",
    "record_session",
    "synthetic_stream",
]

TICK_NS = 33_333_333
START_NS = 1_795_000_000_000_000_000  # 2026-11-18, fixed so that file names are stable


def synthetic_stream(kind: str, n: int, seed: int = 0) -> tuple[Any, Any, list[str]]:
    """``(x (n, d_x), y (n, d_y), labels)`` from the learner's synthetic generators.

    ``"sqrt"``: 1-D two-branch multimap (several experts in ~100 points, fast);
    ``"subtask"``: AIBO-sized 23-D/9-D subtask stream.
    """
    from roger_daemon.learner import synthetic

    if kind == "sqrt":
        s = synthetic.sqrt_multimap(n, seed=seed)
    elif kind == "subtask":
        s = synthetic.subtask_stream(n)
    else:
        raise ValueError(f"stream must be 'sqrt' or 'subtask', got {kind!r}")
    names = ("seek", "trap", "aim", "kick")
    labels = [names[int(v) % len(names)] for v in s.labels]
    return s.x, s.y, labels


class FakeClock:
    """The service's clock: monotonic ns moved by hand; wall clock = start + monotonic."""

    def __init__(self, start_ns: int) -> None:
        self.start_ns = start_ns
        self.mono = 1_000_000_000

    def monotonic_ns(self) -> int:
        return self.mono

    def time_ns(self) -> int:
        return self.start_ns + self.mono


class _Tap(DecisionLog):
    """The robot's real decision log, also keeping each pair the daemon learned."""

    def __init__(self, inner: DecisionLog, pairs: list[tuple[int, Any, Any, str]]) -> None:
        super().__init__(inner.recorders, inner.wall_ns, inner.chain)
        self.pairs = pairs

    def learned(self, rt: RobotRuntime, pair: Pair) -> None:
        self.pairs.append((pair.tick, pair.x, pair.y, rt.vocab[pair.label]))
        super().learned(rt, pair)


@dataclass
class DaemonSession:
    """What the daemon recorded and did."""

    paths: list[Path]
    dims: Dims
    service: Service
    rt: RobotRuntime
    transport: MemoryTransport
    recorder: Any
    checkpoint_dir: Path
    pairs: list[tuple[int, Any, Any, str]] = field(default_factory=list)  # (tick, x, y, label)
    predictions: list[Prediction] = field(default_factory=list)
    checkpoints: dict[int, Any] = field(default_factory=dict)  # n_learned -> state_dict()
    start_state: Any = None  # the state_dict() of the model the session started with

    @property
    def model(self) -> Any:
        """The daemon's model now."""
        return self.rt.model


def record_session(
    directory: str | Path,
    *,
    n_ticks: int = 120,
    robot: str = "sim",
    stream: str = "sqrt",
    seed: int = 7,
    modes: Mapping[int, str] | None = None,
    resets: tuple[int, ...] = (),
    action_first: tuple[int, ...] = (),
    drop_action: tuple[int, ...] = (),
    garbage: tuple[int, ...] = (),
    recorder_options: Mapping[str, Any] | None = None,
    close: bool = True,
    tick0: int = 0,
    checkpoint_at: tuple[int, ...] = (),
    checkpoint_dir: Path | None = None,
    recover: bool = False,
    workers: bool = False,
    daemon: Mapping[str, Any] | None = None,
    robot_options: Mapping[str, Any] | None = None,
) -> DaemonSession:
    """Record a session of ``n_ticks`` ticks (from ``tick0``) with the daemon's own code.

    Each tick: the ``modes`` change or ``resets`` control of that tick, an undecodable
    perception payload on ``garbage`` ticks, then perception and action (action first on
    ``action_first`` ticks, no action on ``drop_action`` ticks); the loop runs until it is
    idle. When the model reaches a count in ``checkpoint_at`` a ``checkpoint`` control makes
    the daemon write a real checkpoint (into ``checkpoint_dir``, default
    ``<directory>/checkpoints``; a checkpoint already there is what the daemon resumes from),
    and its model is kept in :attr:`DaemonSession.checkpoints`. The learner is the paper's
    (``preset = "paper"``, with its ``nu0 = 24``), seed ``seed``. ``close=False`` leaves the
    recorder open, as a killed daemon does (what was flushed is on disk). ``recover``: start
    as ``roger daemon`` does (``start_robots``: start-up self-recovery from the logs already
    in ``directory``).
    ``workers``: the model learns and predicts in a learner worker process
    (``roger_daemon.daemon.learners.ProcessLearners``, ``[daemon] workers = "process"``).
    ``robot_options``: more keys of the robot's ``[[robots]]`` table (e.g. ``model``).
    """
    x, y, labels = synthetic_stream(stream, tick0 + n_ticks, seed=0)
    dims = Dims(int(x.shape[1]), int(y.shape[1]))
    ckdir = Path(checkpoint_dir) if checkpoint_dir is not None else Path(directory) / "checkpoints"
    cfg = parse_config({
        "daemon": {"clock": "lockstep", "seed": seed, **(daemon or {})},
        # the paper's nu0 = 24 (the default is x_dim + 1 since issue 56: 2 for this 1-D stream)
        "learner": {"preset": "paper", "nu0": 24.0},
        "robots": [{"id": robot, "x_dim": dims.x, "y_dim": dims.y, **(robot_options or {})}],
        "checkpoint": {"dir": str(ckdir), "every_updates": 0, "every_s": 0, "wal": False,
                       "on_shutdown": False},
        "recording": {"enabled": True, "dir": str(directory)},
    })
    robot_cfg = cfg.robots[0]
    if recover:
        robots, where = start_robots(cfg, fresh=False)
        rt, resumed = robots[robot], where[robot]
    else:
        rt, ckpt = load_robot(cfg, robot_cfg, fresh=False)
        resumed = Resumed() if ckpt is None else Resumed(
            str(ckpt.path), ckpt.meta.session_id, ckpt.meta.session_segment)
    start_state = rt.model.state_dict()
    options = {"start_ns": START_NS + tick0 * TICK_NS, **(recorder_options or {})}
    recorders = open_recorders(cfg, {robot: rt}, {robot: resumed}, dict(options))
    clock = FakeClock(int(options["start_ns"]))
    transport = MemoryTransport(now_ns=clock.monotonic_ns)
    learners = ProcessLearners({robot: rt}, {robot: robot_cfg}) if workers else None
    service = Service(cfg, transport, {robot: rt}, clock=clock, sync_checkpoints=True,
                      recorders=recorders, resumed={robot: resumed.checkpoint},
                      learners=learners)
    out = DaemonSession(paths=[], dims=dims, service=service, rt=rt, transport=transport,
                        recorder=recorders[robot], checkpoint_dir=ckdir,
                        start_state=start_state)
    assert isinstance(rt.decisions, DecisionLog)
    rt.decisions = _Tap(rt.decisions, out.pairs)
    service.start()

    def send(kind: str, msg: Any) -> None:
        assert transport.inject(keys.key(robot, kind), encode(msg)) >= 1

    for t in range(tick0, tick0 + n_ticks):
        clock.mono += TICK_NS
        if modes and t in modes:
            send("control", Control(robot, t, t / 30, op="mode", mode=modes[t]))
        if t in resets:
            send("control", Control(robot, t, t / 30, op="reset"))
        if t in garbage:
            transport.inject(keys.perception(robot), b"\xc1 not msgpack")
        halves = [("perception", Perception(robot, t, t / 30, x=x[t]))]
        if t not in drop_action:
            halves.append(("action", Action(robot, t, t / 30, y=y[t], label=labels[t])))
        for kind, msg in reversed(halves) if t in action_first else halves:
            send(kind, msg)
        _settle(service, rt)
        if rt.updates in checkpoint_at and rt.updates not in out.checkpoints:
            send("control", Control(robot, t, t / 30, op="checkpoint"))
            _settle(service, rt)
            ck = read_checkpoint(list_checkpoints(ckdir, robot)[0])  # the newest: this one
            out.checkpoints[int(ck.meta.updates)] = ck.model
    out.predictions = [_prediction(data, dims, robot) for _, data in transport.take("prediction")]
    if close:
        service.shutdown()
    out.paths = out.recorder.paths
    return out


def _settle(service: Service, rt: RobotRuntime) -> None:
    for _ in range(1000):
        service.step(0)
        workers = isinstance(service.learners, ProcessLearners)
        if workers:  # every reply of the worker handled
            service.learners.drain()
            service.step(0)
        busy = workers and service.learners.learning()
        if not rt.queue and not len(service.inbox) and not busy:  # every pair learned
            return
    raise AssertionError("the loop did not settle")


def _prediction(data: bytes, dims: Dims, robot: str) -> Prediction:
    msg = decode("prediction", data, dims=dims, robot=robot)
    assert isinstance(msg, Prediction)
    return msg


def as_version_1(src: Path, dst: Path) -> Path:
    """Copy the log ``src`` to ``dst`` as a daemon without decision records wrote it: format
    ``roger-session/1``, and of the decision records only the ``dropped`` ones (older daemons
    wrote those); every other message, time and payload kept."""
    dropped = {"learned", "reset", "model"}

    def keep(topic: str) -> bool:
        decision = keys.parse_decision(topic)
        return decision is None or decision[1] not in dropped

    def version_1(name: str, fields: Mapping[str, str]) -> dict[str, str]:
        return {**fields, "format": FORMAT_INPUTS_ONLY} if name == METADATA_NAME else dict(fields)

    return copy_log(src, dst, keep=keep, metadata=version_1)


def daemon_checkpoint(directory: Path, robot: str, state: Mapping[str, Any], *, dims: Dims,
                      labels: list[str], queue: Sequence[tuple[int, Any, Any, str]] = (),
                      session_id: str = "", segment: int = 0,
                      last_tick: int | None = None) -> Path:
    """Write a daemon checkpoint: model ``state`` (which learned pairs labelled ``labels``),
    ``queue`` pairs ``(tick, x, y, label)`` not learned yet, standing at ``session_id``/
    ``segment`` of the history."""
    vocab = sorted({*labels, *(q[3] for q in queue)}) or [""]
    code = {v: i for i, v in enumerate(vocab)}
    robot_state = RobotState.from_labels(labels, vocab=vocab)
    robot_state.queue = [Pair(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64),
                              code[label], int(tick)) for tick, x, y, label in queue]
    daemon = robot_state.to_arrays(dims)
    meta = CheckpointMeta(reason="test", updates=len(labels), x_dim=dims.x, y_dim=dims.y,
                          session_id=session_id, session_segment=segment,
                          counters=Counters(last_tick=last_tick or 0,
                                            last_learned_tick=last_tick))
    path, _ = write_checkpoint(directory, robot, dict(state), daemon, meta)
    return path
