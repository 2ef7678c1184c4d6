"""Versioned, atomic checkpoints of one robot's model and daemon state (no pickle, ever).

File layout: ``<dir>/<robot>/ckpt-<seq>.npz`` (``seq`` increases by one per write; the
highest valid one is the newest). Each file is an ``np.savez`` archive of named arrays:

- ``model.<name>``: the learner's ``state_dict()`` (it carries the learner's own schema
  version, parameters, dimensions and RNG state);
- ``daemon.<name>``: daemon state (labels of learned pairs, queued-but-unlearned pairs);
- ``meta``: a 0-d unicode array holding a JSON object, a
  :class:`~roger_daemon.daemon.checkpoint_meta.CheckpointMeta` (format, version, robot,
  counters, session position, the learner's identity, ``model_digest``: SHA-256 of the model
  arrays, ``digest``: of every array).

Writes are atomic and durable (:func:`roger_daemon.atomic.atomic_write`: a temporary file in
the same directory, ``fsync``, rename, ``fsync`` of the directory). Reads use
``allow_pickle=False`` and verify the digest, so a truncated, garbled or tampered file raises
:class:`CheckpointError` and is skipped by
:func:`load_newest`. Older versions are upgraded by the functions in ``MIGRATIONS``
(:mod:`roger_daemon.daemon.checkpoint_meta`) before the metadata is parsed.
"""

from __future__ import annotations

import hashlib
import json
import logging
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from roger_daemon.atomic import atomic_write
from roger_daemon.daemon.checkpoint_meta import (
    CHECKPOINT_FORMAT,
    CHECKPOINT_VERSION,
    MIGRATIONS,
    CheckpointMeta,
    MetaError,
    Stored,
)
from roger_daemon.daemon.retention import prune_checkpoints

__all__ = [
    "CHECKPOINT_FORMAT",
    "CHECKPOINT_VERSION",
    "MIGRATIONS",
    "Checkpoint",
    "CheckpointError",
    "CheckpointMeta",
    "Stored",
    "array_digest",
    "list_checkpoints",
    "load_newest",
    "read_checkpoint",
    "write_checkpoint",
]

log = logging.getLogger(__name__)

_NAME = re.compile(r"^ckpt-(\d{8,})\.npz$")


class CheckpointError(Exception):
    """A checkpoint that cannot be used; the message says why."""


@dataclass(frozen=True)
class Checkpoint:
    """A checkpoint as read back: model arrays, daemon arrays and metadata."""

    path: Path | None
    model: dict[str, np.ndarray]
    daemon: dict[str, np.ndarray]
    meta: CheckpointMeta


def array_digest(arrays: Mapping[str, np.ndarray]) -> str:
    """SHA-256 over names, dtypes, shapes and bytes, in name order (hex)."""
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(name.encode())
        h.update(b"\0" + a.dtype.str.encode() + b"\0" + repr(a.shape).encode() + b"\0")
        h.update(a.tobytes())
    return h.hexdigest()


def robot_dir(directory: Path, robot: str) -> Path:
    """Where one robot's checkpoints live."""
    return Path(directory) / robot


def list_checkpoints(directory: Path, robot: str) -> list[Path]:
    """Checkpoint files of ``robot``, newest (highest sequence number) first."""
    d = robot_dir(directory, robot)
    if not d.is_dir():
        return []
    found = []
    for p in d.iterdir():
        m = _NAME.match(p.name)
        if m and p.is_file():
            found.append((int(m.group(1)), p))
    return [p for _, p in sorted(found, reverse=True)]


def _check_arrays(prefix: str, arrays: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    out = {}
    for name, value in arrays.items():
        a = np.asarray(value)
        if a.dtype.hasobject:
            raise CheckpointError(f"{prefix}{name} has object dtype; checkpoints never pickle")
        out[f"{prefix}{name}"] = a
    return out


def write_checkpoint(
    directory: Path,
    robot: str,
    model: Mapping[str, np.ndarray],
    daemon: Mapping[str, np.ndarray],
    meta: CheckpointMeta,
    *,
    keep: int = 5,
    max_bytes: int = 0,
    max_age_s: float = 0.0,
) -> tuple[Path, CheckpointMeta]:
    """Write one checkpoint atomically, prune old ones (``keep``, then the byte and age
    limits of :mod:`roger_daemon.daemon.retention`); return its path and final metadata."""
    d = robot_dir(directory, robot)
    d.mkdir(parents=True, exist_ok=True)
    existing = list_checkpoints(directory, robot)
    seq = int(_NAME.match(existing[0].name).group(1)) + 1 if existing else 1  # type: ignore[union-attr]
    final = d / f"ckpt-{seq:08d}.npz"
    arrays = {**_check_arrays("model.", model), **_check_arrays("daemon.", daemon)}
    full_meta = meta.written(robot, seq, array_digest(dict(model)), array_digest(arrays))
    arrays["meta"] = np.array(full_meta.dumps())
    with atomic_write(final) as f:
        np.savez(f, **arrays)  # type: ignore[arg-type]
    prune_checkpoints(list_checkpoints(directory, robot), keep=keep, max_bytes=max_bytes,
                      max_age_s=max_age_s)
    return final, full_meta


def read_checkpoint(path: Path) -> Checkpoint:
    """Read and verify one checkpoint; raise :class:`CheckpointError` saying what is wrong."""
    try:
        with np.load(path, allow_pickle=False) as npz:
            arrays = {name: npz[name] for name in npz.files}
    except Exception as exc:  # zipfile, numpy and OS errors all mean "unusable"
        raise CheckpointError(f"cannot read archive ({type(exc).__name__}: {exc})") from None
    if "meta" not in arrays:
        raise CheckpointError("no 'meta' entry")
    try:
        meta = json.loads(str(arrays.pop("meta")[()]))
    except (ValueError, IndexError) as exc:
        raise CheckpointError(f"'meta' is not JSON ({exc})") from None
    if not isinstance(meta, dict) or meta.get("format") != CHECKPOINT_FORMAT:
        raise CheckpointError(f"not a {CHECKPOINT_FORMAT} file")
    if array_digest(arrays) != meta.get("digest"):
        raise CheckpointError("digest mismatch (file altered or partially written)")
    model = {k[6:]: v for k, v in arrays.items() if k.startswith("model.")}
    daemon = {k[7:]: v for k, v in arrays.items() if k.startswith("daemon.")}
    stored = _migrated(path, Stored(meta, model, daemon))
    try:
        parsed = CheckpointMeta.from_json(stored.meta)
    except MetaError as exc:
        raise CheckpointError(f"its metadata: {exc}") from None
    return Checkpoint(Path(path), stored.model, stored.daemon, parsed)


def _migrated(path: Path, stored: Stored) -> Stored:
    """``stored`` upgraded to :data:`CHECKPOINT_VERSION` (one logged step per version)."""
    version = stored.meta.get("version")
    if isinstance(version, bool) or not isinstance(version, int) or \
            version > CHECKPOINT_VERSION:
        raise CheckpointError(
            f"version {version!r} is newer than this daemon's {CHECKPOINT_VERSION}"
        )
    while (v := int(stored.meta["version"])) < CHECKPOINT_VERSION:
        if v not in MIGRATIONS:
            raise CheckpointError(f"version {v} has no migration to {v + 1}")
        log.warning("checkpoint %s: migrating from version %d to %d", path, v, v + 1)
        stored = MIGRATIONS[v](stored)
    return stored


def load_newest(
    directory: Path, robot: str, accept: Callable[[Checkpoint], None] | None = None
) -> Checkpoint | None:
    """The newest checkpoint of ``robot`` that reads, verifies and passes ``accept``.

    ``accept`` may raise :class:`CheckpointError` to reject a checkpoint (e.g. wrong
    dimensions). Each rejected file is reported with one WARNING line and skipped.
    """
    for path in list_checkpoints(directory, robot):
        try:
            ckpt = read_checkpoint(path)
            if ckpt.meta.robot != robot:
                raise CheckpointError(f"written for robot {ckpt.meta.robot!r}")
            if accept is not None:
                accept(ckpt)
        except CheckpointError as exc:
            log.warning("skipping corrupt or unusable checkpoint %s: %s", path, exc)
            continue
        return ckpt
    return None
