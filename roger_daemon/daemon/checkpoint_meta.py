"""What a checkpoint says about itself: :class:`CheckpointMeta`, and the migrations of older
formats (docs/durability.md, *Checkpoints*).

Every writer builds a :class:`CheckpointMeta` (the live daemon's snapshots, its ``recovered``
checkpoints, replay's ``--save-checkpoint``, the experiment's model checkpoints) and every
reader gets one back from :func:`roger_daemon.daemon.checkpoint.read_checkpoint`: nothing
assembles or reads a checkpoint's metadata by string keys. On disk it is the JSON object of
the archive's ``meta`` entry (:meth:`CheckpointMeta.to_json`).

Format versions (``version``):

* 1 (until 2026-12-02): a flat JSON object of whatever the writer had at hand; keys missing
  by writer (replay and the experiment wrote no session, no ``wal_seq``, no counters), the
  model's kind, seed and parameters as top-level ``model``/``seed``/``params``, the daemon's
  newest-pair arrays absent before 2026-11-26;
* 2: every field of :class:`CheckpointMeta` present, the learner's identity in one
  ``learner`` object (:class:`LearnerSpec`), the counters complete (:class:`Counters`) and the
  daemon arrays complete (the newest pair as zero rows when there is none).

:data:`MIGRATIONS` upgrades a stored checkpoint one version at a time before it is parsed; a
version-1 checkpoint written by the daemon of that time is kept as a fixture
(``tests/data/checkpoints/v1``) and must keep loading.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np

__all__ = [
    "CHECKPOINT_FORMAT",
    "CHECKPOINT_VERSION",
    "MIGRATIONS",
    "CheckpointMeta",
    "Counters",
    "LearnerSpec",
    "MetaError",
    "Stored",
]

CHECKPOINT_FORMAT = "roger-daemon-checkpoint"
CHECKPOINT_VERSION = 2


class MetaError(ValueError):
    """Metadata that does not describe a checkpoint of this version; the message says why."""


def _int(data: Mapping[str, Any], key: str, *, none: bool = False) -> Any:
    value = data[key]
    if value is None and none:
        return None
    if isinstance(value, bool) or not isinstance(value, int):
        raise MetaError(f"{key} must be an integer{' or null' if none else ''}, got {value!r}")
    return int(value)


def _str(data: Mapping[str, Any], key: str) -> str:
    value = data[key]
    if not isinstance(value, str):
        raise MetaError(f"{key} must be a string, got {value!r}")
    return value


def _strings(data: Mapping[str, Any], key: str) -> tuple[str, ...]:
    value = data[key]
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise MetaError(f"{key} must be a list of strings, got {value!r}")
    return tuple(value)


def _check_keys(data: Any, cls: type, what: str) -> dict[str, Any]:
    if not isinstance(data, dict):
        raise MetaError(f"{what} must be a JSON object, got {data!r}")
    missing = sorted({f.name for f in fields(cls)} - set(data) - {"extra"})
    if missing:
        raise MetaError(f"{what} lacks {', '.join(missing)}")
    return data


@dataclass(frozen=True)
class Counters:
    """A robot runtime's counters (``RobotRuntime.counters``), restored after a restart."""

    ticks: int = 0
    dropped: int = 0
    unpaired_actions: int = 0
    learn_errors: int = 0
    last_tick: int = 0
    last_t: float = 0.0
    mode: str = "learn+predict"
    #: the tick of the newest learned pair (``None``: nothing learned)
    last_learned_tick: int | None = None
    #: rejected messages by reason (the robot's own and those no robot can be blamed for)
    invalid: Mapping[str, int] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """The JSON object of ``meta.counters``."""
        return {"ticks": self.ticks, "dropped": self.dropped,
                "unpaired_actions": self.unpaired_actions, "learn_errors": self.learn_errors,
                "last_tick": self.last_tick, "last_t": float(self.last_t), "mode": self.mode,
                "last_learned_tick": self.last_learned_tick,
                "invalid": {str(k): int(v) for k, v in sorted(self.invalid.items())}}

    @classmethod
    def from_json(cls, data: Any) -> Counters:
        """Parse :meth:`to_json`; :class:`MetaError` names a missing or mistyped field."""
        d = _check_keys(data, cls, "counters")
        last_t = d["last_t"]
        invalid = d["invalid"]
        if isinstance(last_t, bool) or not isinstance(last_t, int | float):
            raise MetaError(f"counters.last_t must be a number, got {last_t!r}")
        if not isinstance(invalid, dict) or not all(
                isinstance(v, int) and not isinstance(v, bool) for v in invalid.values()):
            raise MetaError(f"counters.invalid must map reasons to counts, got {invalid!r}")
        return cls(_int(d, "ticks"), _int(d, "dropped"), _int(d, "unpaired_actions"),
                   _int(d, "learn_errors"), _int(d, "last_tick"), float(last_t),
                   _str(d, "mode"), _int(d, "last_learned_tick", none=True),
                   {str(k): int(v) for k, v in invalid.items()})


@dataclass(frozen=True)
class LearnerSpec:
    """Which learner made the model, as configured: its kind (a name of
    :data:`roger_daemon.learner.registry.MODELS`), seed and parameter mapping
    (``RogerParams.to_mapping``); ``None``: not known to the writer."""

    kind: str = "roger"
    seed: int | None = None
    params: Mapping[str, Any] | None = None

    def to_json(self) -> dict[str, Any]:
        """The JSON object of ``meta.learner``."""
        return {"kind": self.kind, "seed": self.seed,
                "params": None if self.params is None else dict(self.params)}

    @classmethod
    def from_json(cls, data: Any) -> LearnerSpec:
        """Parse :meth:`to_json`."""
        d = _check_keys(data, cls, "learner")
        params = d["params"]
        if params is not None and not isinstance(params, dict):
            raise MetaError(f"learner.params must be an object or null, got {params!r}")
        return cls(_str(d, "kind"), _int(d, "seed", none=True), params)


@dataclass(frozen=True)
class CheckpointMeta:
    """One robot's checkpoint metadata (format :data:`CHECKPOINT_VERSION`).

    A writer gives the fields it knows; :func:`~roger_daemon.daemon.checkpoint.write_checkpoint`
    fills ``robot``, ``sequence`` and the two digests and returns the metadata as written.
    """

    reason: str  # periodic, shutdown, requested, recovered, replay, experiment, ...
    updates: int  # pairs the model learned (its n_learned)
    x_dim: int
    y_dim: int
    robot: str = ""
    created_unix_ns: int = 0
    daemon: str = ""  # the id of the daemon that wrote it ("" : no daemon)
    counters: Counters = field(default_factory=Counters)
    #: where in the session logs the model stands: the recorder's session ("" without one)
    #: and the resets before it in that session (start-up recovery reads the log from there)
    session_id: str = ""
    session_segment: int = 0
    #: the write-ahead log's last record reflected in the snapshot (``None``: no log)
    wal_seq: int | None = None
    learner: LearnerSpec = field(default_factory=LearnerSpec)
    recovered_pairs: int = 0  # pairs re-learned at start-up before it was written
    recovered_from: tuple[str, ...] = ()  # the sessions they came from
    replayed_from: tuple[str, ...] = ()  # replay's --save-checkpoint: the files replayed
    version: int = CHECKPOINT_VERSION
    sequence: int = 0  # its number among the robot's checkpoints (the file's name)
    model_digest: str = ""  # array_digest of the model arrays
    digest: str = ""  # array_digest of every array of the file
    #: keys of the stored object this version does not know (kept, never interpreted)
    extra: Mapping[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """The JSON object stored as the archive's ``meta`` entry."""
        out: dict[str, Any] = {**self.extra, "format": CHECKPOINT_FORMAT}
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "extra":
                continue
            if isinstance(value, Counters | LearnerSpec):
                value = value.to_json()
            elif isinstance(value, tuple):
                value = list(value)
            out[f.name] = value
        return out

    def dumps(self) -> str:
        """:meth:`to_json` as JSON text (sorted keys)."""
        return json.dumps(self.to_json(), sort_keys=True)

    @classmethod
    def from_json(cls, data: Any) -> CheckpointMeta:
        """Parse a version-:data:`CHECKPOINT_VERSION` object; :class:`MetaError` names what
        is missing or mistyped (older versions are migrated first: :data:`MIGRATIONS`)."""
        d = _check_keys(data, cls, "meta")
        if d.get("format") != CHECKPOINT_FORMAT:
            raise MetaError(f"not a {CHECKPOINT_FORMAT} file")
        if d["version"] != CHECKPOINT_VERSION:
            raise MetaError(f"version {d['version']!r} is not {CHECKPOINT_VERSION}")
        known = {f.name for f in fields(cls)} | {"format"}
        return cls(
            reason=_str(d, "reason"), updates=_int(d, "updates"), x_dim=_int(d, "x_dim"),
            y_dim=_int(d, "y_dim"), robot=_str(d, "robot"),
            created_unix_ns=_int(d, "created_unix_ns"), daemon=_str(d, "daemon"),
            counters=Counters.from_json(d["counters"]), session_id=_str(d, "session_id"),
            session_segment=_int(d, "session_segment"), wal_seq=_int(d, "wal_seq", none=True),
            learner=LearnerSpec.from_json(d["learner"]),
            recovered_pairs=_int(d, "recovered_pairs"),
            recovered_from=_strings(d, "recovered_from"),
            replayed_from=_strings(d, "replayed_from"), version=_int(d, "version"),
            sequence=_int(d, "sequence"), model_digest=_str(d, "model_digest"),
            digest=_str(d, "digest"), extra={k: v for k, v in d.items() if k not in known})

    def written(self, robot: str, sequence: int, model_digest: str, digest: str
                ) -> CheckpointMeta:
        """This metadata as :func:`~roger_daemon.daemon.checkpoint.write_checkpoint` stores it."""
        return replace(self, robot=robot, version=CHECKPOINT_VERSION, sequence=sequence,
                       model_digest=model_digest, digest=digest)


@dataclass(frozen=True)
class Stored:
    """A checkpoint as stored, before it is parsed: its metadata object and its arrays (what a
    migration rewrites)."""

    meta: dict[str, Any]
    model: dict[str, np.ndarray]
    daemon: dict[str, np.ndarray]


def _model_kind(model: Mapping[str, np.ndarray]) -> str:
    """The kind a model state dict names in its own ``meta`` (``"roger"`` if it names none)."""
    from roger_daemon.learner.state import unpack_meta

    try:
        kind = unpack_meta(model).get("kind")
    except ValueError:
        return "roger"
    return kind if isinstance(kind, str) else "roger"


_V1_DEFAULTS: dict[str, Any] = {
    "created_unix_ns": 0, "daemon": "", "session_id": "", "session_segment": 0,
    "wal_seq": None, "recovered_pairs": 0, "recovered_from": [], "replayed_from": [],
    "sequence": 0, "x_dim": 0, "y_dim": 0, "reason": "", "updates": 0,
}
_NEWEST = ("newest_pair_tick", "newest_pair_x", "newest_pair_y")


def _v1_to_v2(old: Stored) -> Stored:
    """Version 1 -> 2: the fields a version-1 writer left out take the values its readers
    assumed for them; ``model``/``seed``/``params`` become ``learner``; the counters are
    completed; a daemon state without the newest-pair arrays (before 2026-11-26) gets them,
    empty (no newest pair: what its readers read)."""
    meta = {**_V1_DEFAULTS, **old.meta, "version": 2}
    for key in ("session_id", "daemon"):  # written as null by some writers
        meta[key] = meta[key] or ""
    meta["session_segment"] = int(meta["session_segment"] or 0)
    if "learner" not in meta:
        meta["learner"] = {"kind": meta.pop("model", None) or _model_kind(old.model),
                           "seed": meta.pop("seed", None), "params": meta.pop("params", None)}
    counters = meta.get("counters")
    meta["counters"] = {**Counters().to_json(), **(counters if isinstance(counters, dict)
                                                   else {})}
    daemon = dict(old.daemon)
    if "queue_x" in daemon and not all(k in daemon for k in _NEWEST):
        d_x, d_y = int(meta["x_dim"]), int(meta["y_dim"])
        daemon.update(newest_pair_tick=np.zeros(0, dtype=np.int64),
                      newest_pair_x=np.zeros((0, d_x)), newest_pair_y=np.zeros((0, d_y)))
    return Stored(meta, old.model, daemon)


#: version -> function upgrading a stored checkpoint of that version to version + 1.
MIGRATIONS: dict[int, Callable[[Stored], Stored]] = {1: _v1_to_v2}
