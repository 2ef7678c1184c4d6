"""The message types of the ROGER wire (frozen dataclasses), their limits, and ``encode``.

A prediction's bytes without the dataclasses (a learner worker's fast path) are in
:mod:`protocols.prediction_bytes`.

The field tables live in ``protocols/README.md``; decoding and validation are in
:mod:`protocols.decoding`; :mod:`protocols.messages` has both. Each field's description and
constraints sit next to it (``field(metadata=spec(...))``, :mod:`protocols.field_specs`), and
each class's ``DESCRIPTION`` describes its kind: the MCAP files' JSON Schemas are generated from
them (``roger_daemon.recording.schemas``).
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
import numpy.typing as npt

from protocols.field_specs import spec
from protocols.keys import ROBOT_ID_PATTERN
from protocols.packing import packb

__all__ = [
    "CONTROL_OPS",
    "MAX_MAP_ENTRIES",
    "MAX_MULTIMAP",
    "MAX_STR",
    "MAX_VECTOR",
    "EPISODE_EVENTS",
    "MAX_PAYLOAD_BYTES",
    "MODES",
    "SCHEMA_VERSION",
    "SOURCES",
    "Action",
    "Command",
    "Control",
    "Dims",
    "EpisodeEvent",
    "ExpertOutput",
    "Message",
    "Perception",
    "Prediction",
    "Status",
    "TYPES",
    "FloatArray",
    "as_vector",
    "encode",
    "expert_output_map",
    "header_map",
    "now_ns",
    "prediction_body",
]

SCHEMA_VERSION = 1
MAX_PAYLOAD_BYTES = 64 * 1024
MAX_VECTOR = 1024
MAX_STR = 256
MAX_MULTIMAP = 512
MAX_MAP_ENTRIES = 128  # a daemon status's info has ~66 keys with learner workers and a standby
MODES = ("learn", "predict", "learn+predict", "pause")
CONTROL_OPS = ("mode", "reset", "checkpoint")
#: who commanded an action (``Action.source``): a teacher (a person, a hand-coded
#: controller), the robot itself, or unknown (docs/datasets.md, docs/teach.md)
SOURCES = ("", "teacher", "robot")
EPISODE_EVENTS = ("start", "goal", "own_goal", "out", "timeout", "end", "truth")

FloatArray = npt.NDArray[np.float64]


def now_ns() -> int:
    """The sender's wall clock for ``stamp_ns``."""
    return time.time_ns()


@dataclass(frozen=True)
class Dims:
    """Expected vector sizes: ``x`` perception, ``y`` action/command/prediction mean."""

    x: int
    y: int


def as_vector(values: Any) -> FloatArray:
    """``values`` as a read-only float64 vector."""
    arr = np.array(values, dtype=np.float64).reshape(-1)
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class Message:
    """Header shared by every message.

    Every field carries its description and constraints (:class:`~protocols.field_specs.FieldSpec`)
    in its metadata; ``DESCRIPTION`` describes the kind (both go into the JSON Schemas).
    """

    robot: str = field(metadata=spec(
        "robot id, the same as in the key expression roger/<robot>/<kind>",
        pattern=ROBOT_ID_PATTERN))
    tick: int = field(metadata=spec(
        "control tick the message belongs to (the MCAP sequence field)"))
    t: float = field(metadata=spec("simulation (or robot) time in seconds"))
    stamp_ns: int = field(default_factory=now_ns, kw_only=True, metadata=spec(
        "sender's wall clock, ns since the Unix epoch (the MCAP publish_time)"))

    KIND: ClassVar[str] = ""
    DESCRIPTION: ClassVar[str] = ""
    VERSION_DESCRIPTION: ClassVar[str] = "schema version of the ROGER wire"

    def header(self) -> dict[str, Any]:
        """The header fields as a msgpack-ready map."""
        return header_map(self.robot, self.tick, self.t, self.stamp_ns)

    def body(self) -> dict[str, Any]:
        """The kind-specific fields (overridden)."""
        return {}

    def to_map(self) -> dict[str, Any]:
        """The whole message as a plain map (also what the JSON export writes)."""
        return {**self.header(), **self.body()}


@dataclass(frozen=True, eq=False)
class Perception(Message):
    """What the robot senses at ``tick``: ``x``, ``Dims.x`` floats."""

    x: FloatArray = field(metadata=spec("perception vector, Dims.x floats"))

    KIND: ClassVar[str] = "perception"
    DESCRIPTION: ClassVar[str] = (
        "What the robot senses at `tick` (23 floats for the AIBO; see protocols/aibo.py).")

    def __post_init__(self) -> None:
        object.__setattr__(self, "x", as_vector(self.x))

    def body(self) -> dict[str, Any]:
        """The message's own fields as a msgpack-ready map (the envelope is added by ``encode``)."""
        return {"x": self.x.tolist()}


@dataclass(frozen=True, eq=False)
class Action(Message):
    """The demonstrator's action for the perception of the same ``tick``, with its subtask label.

    The label is ground truth for evaluation and for grouping experts; it never enters the learner.
    """

    y: FloatArray = field(metadata=spec("action vector, Dims.y floats"))
    label: str = field(default="", metadata=spec("the demonstrator's subtask label"))
    source: str = field(default="", metadata=spec(
        "who commanded the action: 'teacher', 'robot' or '' (unknown)", choices=SOURCES))
    correction: bool = field(default=False, metadata=spec(
        "the teacher took over from the robot on this tick (a human-gated correction)",
        minimum=None))

    KIND: ClassVar[str] = "action"
    DESCRIPTION: ClassVar[str] = (
        "The demonstrator's action for the perception of the same tick, with its subtask label "
        "(evaluation only; never enters the learner).")

    def __post_init__(self) -> None:
        object.__setattr__(self, "y", as_vector(self.y))

    def body(self) -> dict[str, Any]:
        """The message's own fields as a msgpack-ready map (the envelope is added by ``encode``)."""
        return {"y": self.y.tolist(), "label": self.label, "source": self.source,
                "correction": bool(self.correction)}


@dataclass(frozen=True, eq=False)
class Command(Message):
    """What the robot is told to do at ``tick``; ``source`` names the controller."""

    y: FloatArray = field(metadata=spec("command vector, Dims.y floats"))
    source: str = field(default="", metadata=spec("the controller that produced it"))

    KIND: ClassVar[str] = "command"
    DESCRIPTION: ClassVar[str] = "What the robot is told to do at `tick`."

    def __post_init__(self) -> None:
        object.__setattr__(self, "y", as_vector(self.y))

    def body(self) -> dict[str, Any]:
        """The message's own fields as a msgpack-ready map (the envelope is added by ``encode``)."""
        return {"y": self.y.tolist(), "source": self.source}


@dataclass(frozen=True, eq=False)
class ExpertOutput:
    """One expert of the MAP particle, as seen from one query perception."""

    expert: int = field(metadata=spec("expert id, unique over the life of the model", minimum=-1))
    p: float = field(metadata=spec("gate probability of this expert for the query perception"))
    mean: FloatArray = field(metadata=spec("predictive mean of this expert (action units)"))
    var: FloatArray = field(metadata=spec("predictive variance of this expert, > 0",
                                          positive=True))
    n: int = field(metadata=spec("training points assigned to this expert"))
    label: str = field(default="", metadata=spec(
        "majority subtask label of the expert's points ('' if none)"))

    DESCRIPTION: ClassVar[str] = "one expert of the MAP particle, as seen from the query perception"

    def __post_init__(self) -> None:
        object.__setattr__(self, "mean", as_vector(self.mean))
        object.__setattr__(self, "var", as_vector(self.var))

    def to_map(self) -> dict[str, Any]:
        """Plain map for msgpack/JSON."""
        return expert_output_map(self.expert, self.p, self.mean, self.var, self.n, self.label)


@dataclass(frozen=True, eq=False)
class Prediction(Message):
    """The learner's answer for the perception of ``tick``.

    ``mean``/``var`` are the chosen expert's predictive mean and variance (per output, in action
    units); ``expert`` its id (-1 when the model has no expert yet); ``multimap`` every expert of
    the MAP particle; ``latency_ms`` from perception receipt to publish; ``updates`` the number
    of training pairs the model had learned when it computed this prediction (so that a replay
    can recompute it from the same model state).
    """

    mean: FloatArray = field(metadata=spec("chosen expert's predictive mean (action units)"))
    var: FloatArray = field(metadata=spec("chosen expert's predictive variance, > 0",
                                          positive=True))
    expert: int = field(metadata=spec("chosen expert id, -1 before any learning", minimum=-1))
    multimap: tuple[ExpertOutput, ...] = field(default=(), metadata=spec(
        "every expert of the MAP particle"))
    latency_ms: float = field(default=0.0, metadata=spec("from perception receipt to publish, ms"))
    mode: str = field(default="learn+predict", metadata=spec("daemon mode", choices=MODES))
    updates: int = field(default=0, metadata=spec(
        "training pairs the model had learned when it computed this prediction"))

    KIND: ClassVar[str] = "prediction"
    DESCRIPTION: ClassVar[str] = "The learner's answer for the perception of `tick`."

    def __post_init__(self) -> None:
        object.__setattr__(self, "mean", as_vector(self.mean))
        object.__setattr__(self, "var", as_vector(self.var))
        object.__setattr__(self, "multimap", tuple(self.multimap))

    def body(self) -> dict[str, Any]:
        """The message's own fields as a msgpack-ready map (the envelope is added by ``encode``)."""
        return prediction_body(self.mean, self.var, self.expert,
                               [e.to_map() for e in self.multimap], self.latency_ms, self.mode,
                               self.updates)


@dataclass(frozen=True, eq=False)
class EpisodeEvent(Message):
    """An episode event from the simulator; ``data`` holds small named values (pose, location)."""

    event: str = field(metadata=spec("what happened", choices=EPISODE_EVENTS))
    episode: int = field(metadata=spec("episode number"))
    data: Mapping[str, Any] = field(default_factory=dict, metadata=spec(
        "small named values (pose, location, ...)"))

    KIND: ClassVar[str] = "episode"
    DESCRIPTION: ClassVar[str] = "An episode event from the simulator."

    def body(self) -> dict[str, Any]:
        """The message's own fields as a msgpack-ready map (the envelope is added by ``encode``)."""
        return {"event": self.event, "episode": int(self.episode), "data": dict(self.data)}


@dataclass(frozen=True, eq=False)
class Status(Message):
    """Daemon health for one robot, published at 1 Hz."""

    daemon: str = field(metadata=spec("daemon id"))
    mode: str = field(metadata=spec("daemon mode", choices=MODES))
    ticks: int = field(metadata=spec("loop ticks so far"))
    updates: int = field(metadata=spec("training pairs learned so far"))
    updates_per_s: float = field(metadata=spec("learning rate, pairs per second"))
    experts: int = field(metadata=spec("experts in the MAP particle"))
    queue_depth: int = field(metadata=spec("messages waiting in the daemon's queues"))
    dropped: int = field(metadata=spec("messages dropped so far"))
    invalid: Mapping[str, int] = field(default_factory=dict, metadata=spec(
        "invalid messages by ProtocolError reason"))
    latency_ms_p50: float = field(default=0.0, metadata=spec("median prediction latency, ms"))
    latency_ms_p99: float = field(default=0.0, metadata=spec(
        "99th percentile prediction latency, ms"))
    uptime_s: float = field(default=0.0, metadata=spec("seconds since the daemon started"))
    info: Mapping[str, Any] = field(default_factory=dict, metadata=spec(
        "free-form extra health values"))

    KIND: ClassVar[str] = "status"
    DESCRIPTION: ClassVar[str] = "Daemon health for one robot, 1 Hz."

    def body(self) -> dict[str, Any]:
        """The message's own fields as a msgpack-ready map (the envelope is added by ``encode``)."""
        return {
            "daemon": self.daemon,
            "mode": self.mode,
            "ticks": int(self.ticks),
            "updates": int(self.updates),
            "updates_per_s": float(self.updates_per_s),
            "experts": int(self.experts),
            "queue_depth": int(self.queue_depth),
            "dropped": int(self.dropped),
            "invalid": {str(k): int(v) for k, v in self.invalid.items()},
            "latency_ms_p50": float(self.latency_ms_p50),
            "latency_ms_p99": float(self.latency_ms_p99),
            "uptime_s": float(self.uptime_s),
            "info": dict(self.info),
        }


@dataclass(frozen=True, eq=False)
class Control(Message):
    """A request to the daemon: ``op`` is ``mode`` (with ``mode``), ``reset`` or ``checkpoint``."""

    op: str = field(metadata=spec("the request", choices=CONTROL_OPS))
    mode: str = field(default="", metadata=spec("the new mode for op 'mode', else ''"))

    KIND: ClassVar[str] = "control"
    DESCRIPTION: ClassVar[str] = (
        "A request to the daemon: op 'mode' (with mode), 'reset' or 'checkpoint'.")

    def body(self) -> dict[str, Any]:
        """The message's own fields as a msgpack-ready map (the envelope is added by ``encode``)."""
        return {"op": self.op, "mode": self.mode}


TYPES: dict[str, type[Message]] = {
    cls.KIND: cls
    for cls in (Perception, Action, Command, Prediction, EpisodeEvent, Status, Control)
}


def encode(msg: Message) -> bytes:
    """Serialise a message to msgpack bytes."""
    return packb(msg.to_map())


# The wire maps of a header, a prediction and one multimap entry: the one place their fields
# are written (the dataclasses' ``header``/``body``/``to_map`` and encode_prediction).

def header_map(robot: str, tick: int, t: float, stamp_ns: int) -> dict[str, Any]:
    """The header fields of every message as a msgpack-ready map."""
    return {"v": SCHEMA_VERSION, "robot": robot, "tick": int(tick), "t": float(t),
            "stamp_ns": int(stamp_ns)}


def _float_list(values: Any) -> list[float]:
    """``values`` as a flat list of floats: ``np.asarray(values, float64).reshape(-1)
    .tolist()``, straight from ``tolist`` for what a model gives, a 1-D float64 array (a
    micro-second less per vector, 26 of them in a prediction with 13 experts), and as it is
    for a list of floats (a row of ``tolist`` of a matrix: a daemon's multimap rows)."""
    if type(values) is np.ndarray and values.dtype == np.float64 and values.ndim == 1:
        fast: list[float] = values.tolist()
        return fast
    if type(values) is list and all(type(v) is float for v in values):
        return values
    out: list[float] = np.asarray(values, dtype=np.float64).reshape(-1).tolist()
    return out


def expert_output_map(expert: int, p: float, mean: Any, var: Any, n: int,
                      label: str) -> dict[str, Any]:
    """One multimap entry (:class:`ExpertOutput`) as a msgpack-ready map."""
    return {"expert": int(expert), "p": float(p), "mean": _float_list(mean),
            "var": _float_list(var), "n": int(n), "label": label}


def prediction_body(mean: Any, var: Any, expert: int, multimap: list[dict[str, Any]],
                    latency_ms: float, mode: str, updates: int) -> dict[str, Any]:
    """A prediction's own fields (:class:`Prediction`), ``multimap`` already as maps."""
    return {"mean": _float_list(mean), "var": _float_list(var), "expert": int(expert),
            "multimap": multimap, "latency_ms": float(latency_ms), "mode": mode,
            "updates": int(updates)}
