"""Decoding and validating ROGER messages: msgpack bytes to a message, or ``ProtocolError``.

``decode`` validates type, header, dimensions, finiteness and size, and raises
:class:`~protocols.errors.ProtocolError` naming the reason (``protocols/README.md``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import msgpack
import numpy as np

from protocols.errors import ProtocolError
from protocols.keys import validate_robot_id
from protocols.message_types import (
    CONTROL_OPS,
    EPISODE_EVENTS,
    MAX_MAP_ENTRIES,
    MAX_MULTIMAP,
    MAX_PAYLOAD_BYTES,
    MAX_STR,
    MAX_VECTOR,
    MODES,
    SCHEMA_VERSION,
    SOURCES,
    TYPES,
    Action,
    Command,
    Control,
    Dims,
    EpisodeEvent,
    ExpertOutput,
    FloatArray,
    Message,
    Perception,
    Prediction,
    Status,
    as_vector,
)

__all__ = ["decode"]

def _get(m: Mapping[str, Any], name: str, kind: str) -> Any:
    if name not in m:
        raise ProtocolError("missing_field", f"{kind}: field {name!r} is missing")
    return m[name]


def _int(m: Mapping[str, Any], name: str, kind: str, *, lo: int | None = None) -> int:
    v = _get(m, name, kind)
    if isinstance(v, bool) or not isinstance(v, int):
        raise ProtocolError(
            "wrong_type", f"{kind}: {name!r} must be an integer, got {type(v).__name__}"
        )
    if lo is not None and v < lo:
        raise ProtocolError("bad_value", f"{kind}: {name!r} must be >= {lo}, got {v}")
    return v


def _float(m: Mapping[str, Any], name: str, kind: str, *, finite: bool = True) -> float:
    v = _get(m, name, kind)
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise ProtocolError(
            "wrong_type", f"{kind}: {name!r} must be a number, got {type(v).__name__}"
        )
    f = float(v)
    if finite and not math.isfinite(f):
        raise ProtocolError("not_finite", f"{kind}: {name!r} must be finite, got {f}")
    return f


def _no_ext(code: int, data: bytes) -> Any:
    """msgpack ext_hook: extension types are not part of the protocol (even empty ones)."""
    raise ValueError(f"extension type {code} ({len(data)} bytes) is not allowed")


def _str(m: Mapping[str, Any], name: str, kind: str, *, choices: tuple[str, ...] = ()) -> str:
    v = _get(m, name, kind)
    if not isinstance(v, str):
        raise ProtocolError(
            "wrong_type", f"{kind}: {name!r} must be a string, got {type(v).__name__}"
        )
    # (a string of at most MAX_STR // 4 characters cannot exceed MAX_STR UTF-8 bytes)
    if len(v) > MAX_STR // 4 and len(v.encode("utf-8")) > MAX_STR:
        raise ProtocolError("oversized", f"{kind}: {name!r} longer than {MAX_STR} bytes (UTF-8)")
    if choices and v not in choices:
        raise ProtocolError("bad_value", f"{kind}: {name!r} must be one of {choices}, got {v!r}")
    return v


def _bool(m: Mapping[str, Any], name: str, kind: str) -> bool:
    v = _get(m, name, kind)
    if not isinstance(v, bool):
        raise ProtocolError(
            "wrong_type", f"{kind}: {name!r} must be true or false, got {type(v).__name__}"
        )
    return v


def _action(head: dict[str, Any], m: Mapping[str, Any], dy: int | None) -> Action:
    """An action; ``source`` and ``correction`` (issue 54) are absent from the logs written
    before them and read as ``""`` and ``false`` there (protocols/README.md)."""
    kind = "action"
    source = _str(m, "source", kind, choices=SOURCES) if "source" in m else ""
    correction = _bool(m, "correction", kind) if "correction" in m else False
    return Action(**head, y=_vector(m, "y", kind, dy), label=_str(m, "label", kind),
                  source=source, correction=correction)


_PLAIN_NUMBERS = frozenset((int, float))  # what msgpack decodes numbers to (bool is not one)


def _vector(
    m: Mapping[str, Any], name: str, kind: str, dim: int | None, *, positive: bool = False
) -> FloatArray:
    v = _get(m, name, kind)
    if not isinstance(v, list | tuple):
        raise ProtocolError(
            "wrong_type", f"{kind}: {name!r} must be an array of numbers, got {type(v).__name__}"
        )
    if len(v) > MAX_VECTOR:
        raise ProtocolError("oversized", f"{kind}: {name!r} has {len(v)} > {MAX_VECTOR} entries")
    if not _PLAIN_NUMBERS.issuperset(map(type, v)) and \
            any(isinstance(e, bool) or not isinstance(e, int | float) for e in v):
        raise ProtocolError("wrong_type", f"{kind}: {name!r} must contain only numbers")
    if dim is not None and len(v) != dim:
        raise ProtocolError(
            "wrong_dimension", f"{kind}: {name!r} must have {dim} entries, got {len(v)}"
        )
    arr = as_vector(v)
    if not np.all(np.isfinite(arr)):
        raise ProtocolError("not_finite", f"{kind}: {name!r} contains NaN or infinity")
    if positive and np.any(arr <= 0):
        raise ProtocolError("bad_value", f"{kind}: {name!r} must be > 0 everywhere")
    return arr


def _small_map(m: Mapping[str, Any], name: str, kind: str) -> dict[str, Any]:
    v = _get(m, name, kind)
    if not isinstance(v, dict):
        raise ProtocolError(
            "wrong_type", f"{kind}: {name!r} must be a map, got {type(v).__name__}"
        )
    if len(v) > MAX_MAP_ENTRIES:
        raise ProtocolError("oversized", f"{kind}: {name!r} has more than {MAX_MAP_ENTRIES} keys")
    for k in v:
        if not isinstance(k, str):
            raise ProtocolError("wrong_type", f"{kind}: keys of {name!r} must be strings")
    return dict(v)


def _expert(e: Any, dim: int | None) -> ExpertOutput:
    kind = "prediction.multimap[]"
    if not isinstance(e, dict):
        raise ProtocolError("wrong_type", f"{kind}: each entry must be a map")
    return ExpertOutput(
        expert=_int(e, "expert", kind, lo=-1),
        p=_float(e, "p", kind),
        mean=_vector(e, "mean", kind, dim),
        var=_vector(e, "var", kind, dim, positive=True),
        n=_int(e, "n", kind, lo=0),
        label=_str(e, "label", kind),
    )


def _experts(mm: list[Any], dim: int | None) -> tuple[ExpertOutput, ...]:
    """Every multimap entry, validated as :func:`_expert` does: the vectors of all entries in
    one array pass when they are well formed (the transitioner decodes one multimap per tick);
    otherwise entry by entry, which raises the entry's own error."""
    vectors = _well_formed_vectors(mm, dim)
    if vectors is None:
        return tuple(_expert(e, dim) for e in mm)
    means, variances = vectors
    kind = "prediction.multimap[]"
    return tuple(
        ExpertOutput(expert=_int(e, "expert", kind, lo=-1), p=_float(e, "p", kind),
                     mean=means[i], var=variances[i], n=_int(e, "n", kind, lo=0),
                     label=_str(e, "label", kind))
        for i, e in enumerate(mm)
    )


def _well_formed_vectors(mm: list[Any], dim: int | None
                         ) -> tuple[FloatArray, FloatArray] | None:
    """(means, variances) as 2-D arrays if every entry's are finite numbers of one length
    (``dim`` if given; variances > 0), else ``None``."""
    if not mm or not all(type(e) is dict for e in mm):
        return None
    rows = [e.get("mean") for e in mm] + [e.get("var") for e in mm]
    width = len(rows[0]) if type(rows[0]) is list else -1
    if width < 0 or (dim is not None and width != dim) or width > MAX_VECTOR:
        return None
    if not all(type(r) is list and len(r) == width for r in rows):
        return None
    if not all(type(v) is float or type(v) is int for r in rows for v in r):
        return None
    arr = np.array(rows, dtype=np.float64).reshape(len(rows), width)
    half = len(mm)
    if not np.isfinite(arr).all() or not (arr[half:] > 0).all():
        return None
    return arr[:half], arr[half:]


def _unpack(kind: str, payload: bytes | bytearray | memoryview, max_bytes: int
            ) -> dict[Any, Any]:
    """Bounded msgpack parse of one payload; the top level must be a map."""
    raw = bytes(payload)
    if len(raw) > max_bytes:
        raise ProtocolError("oversized", f"{kind}: payload of {len(raw)} bytes > {max_bytes}")
    try:
        m = msgpack.unpackb(
            raw,
            raw=False,
            strict_map_key=True,
            max_str_len=4 * MAX_STR,
            max_bin_len=max_bytes,
            max_array_len=max(MAX_VECTOR, MAX_MULTIMAP),
            max_map_len=MAX_MAP_ENTRIES,
            max_ext_len=0,
            ext_hook=_no_ext,
        )
    except Exception as exc:  # msgpack raises several unrelated types for bad bytes
        raise ProtocolError("not_msgpack", f"{kind}: payload is not msgpack ({exc})") from None
    if not isinstance(m, dict):
        raise ProtocolError("not_a_map", f"{kind}: top level must be a map, got {type(m).__name__}")
    return m


def _header(kind: str, m: dict[Any, Any], robot: str | None) -> dict[str, Any]:
    """Schema version, robot id (against the key's), tick, sim time and stamp of a message."""
    version = m.get("v")
    if isinstance(version, bool) or not isinstance(version, int):
        raise ProtocolError("bad_version", f"{kind}: schema version 'v' missing or not an integer")
    if version != SCHEMA_VERSION:
        raise ProtocolError(
            "bad_version",
            f"{kind}: schema version {version} not supported (this is {SCHEMA_VERSION})",
        )
    who = _str(m, "robot", kind)
    try:
        validate_robot_id(who)
    except ProtocolError as exc:
        raise ProtocolError("bad_value", f"{kind}: {exc.detail}") from None
    if robot is not None and who != robot:
        raise ProtocolError(
            "unknown_robot", f"{kind}: payload robot {who!r} does not match key robot {robot!r}"
        )
    head: dict[str, Any] = {
        "robot": who,
        "tick": _int(m, "tick", kind, lo=0),
        "t": _float(m, "t", kind),
        "stamp_ns": _int(m, "stamp_ns", kind, lo=0),
    }
    return head


def decode(
    kind: str,
    payload: bytes | bytearray | memoryview,
    *,
    dims: Dims | None = None,
    robot: str | None = None,
    max_bytes: int = MAX_PAYLOAD_BYTES,
) -> Message:
    """Decode and validate one payload of ``kind`` (one of ``protocols.keys.KINDS``).

    Parameters
    ----------
    kind
        The message kind, usually the last segment of the key expression.
    payload
        The raw bytes.
    dims
        Expected vector sizes; ``None`` checks only that vectors are vectors.
    robot
        The robot id of the key expression the payload came on; the payload must carry the same.
    max_bytes
        Payloads larger than this are rejected before parsing.
    """
    if kind not in TYPES:
        raise ProtocolError("bad_key", f"unknown message kind {kind!r}")
    m = _unpack(kind, payload, max_bytes)
    head = _header(kind, m, robot)
    dx = dims.x if dims else None
    dy = dims.y if dims else None
    if kind == "perception":
        return Perception(**head, x=_vector(m, "x", kind, dx))
    if kind == "action":
        return _action(head, m, dy)
    if kind == "command":
        return Command(**head, y=_vector(m, "y", kind, dy), source=_str(m, "source", kind))
    if kind == "prediction":
        mm = _get(m, "multimap", kind)
        if not isinstance(mm, list):
            raise ProtocolError("wrong_type", f"{kind}: 'multimap' must be an array")
        if len(mm) > MAX_MULTIMAP:
            raise ProtocolError("oversized", f"{kind}: multimap has more than {MAX_MULTIMAP}")
        return Prediction(
            **head,
            mean=_vector(m, "mean", kind, dy),
            var=_vector(m, "var", kind, dy, positive=True),
            expert=_int(m, "expert", kind, lo=-1),
            multimap=_experts(mm, dy),
            latency_ms=_float(m, "latency_ms", kind),
            mode=_str(m, "mode", kind, choices=MODES),
            updates=_int(m, "updates", kind, lo=0),
        )
    if kind == "episode":
        return EpisodeEvent(
            **head,
            event=_str(m, "event", kind, choices=EPISODE_EVENTS),
            episode=_int(m, "episode", kind, lo=0),
            data=_small_map(m, "data", kind),
        )
    if kind == "status":
        invalid = _small_map(m, "invalid", kind)
        for k, v in invalid.items():
            if isinstance(v, bool) or not isinstance(v, int):
                raise ProtocolError("wrong_type", f"{kind}: invalid[{k!r}] must be an integer")
        return Status(
            **head,
            daemon=_str(m, "daemon", kind),
            mode=_str(m, "mode", kind, choices=MODES),
            ticks=_int(m, "ticks", kind, lo=0),
            updates=_int(m, "updates", kind, lo=0),
            updates_per_s=_float(m, "updates_per_s", kind),
            experts=_int(m, "experts", kind, lo=0),
            queue_depth=_int(m, "queue_depth", kind, lo=0),
            dropped=_int(m, "dropped", kind, lo=0),
            invalid=invalid,
            latency_ms_p50=_float(m, "latency_ms_p50", kind),
            latency_ms_p99=_float(m, "latency_ms_p99", kind),
            uptime_s=_float(m, "uptime_s", kind),
            info=_small_map(m, "info", kind),
        )
    # control
    op = _str(m, "op", kind, choices=CONTROL_OPS)
    mode = _str(m, "mode", kind) if op == "mode" or "mode" in m else ""
    if op == "mode" and mode not in MODES:
        raise ProtocolError("bad_value", f"{kind}: op 'mode' needs 'mode' in {MODES}, got {mode!r}")
    return Control(**head, op=op, mode=mode)
