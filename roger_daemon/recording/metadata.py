"""The session metadata record: config, learner params, dims, seed and versions.

Every MCAP file (every rotated part too) holds one metadata record named ``roger.session``
(:data:`METADATA_NAME`), a ``{str: str}`` map. The daemon builds it with
:func:`session_metadata` and hands it to :class:`~roger_daemon.recording.SessionRecorder`, which
adds the recorder's own keys (session id, part, start time). Replay and log-tail catch-up read it
back with :func:`SessionInfo.from_metadata`.
"""

from __future__ import annotations

import json
import platform
import socket
from collections.abc import Mapping
from dataclasses import dataclass
from importlib import metadata as importlib_metadata
from pathlib import Path
from typing import Any

from protocols.messages import MODES, Dims
from roger_daemon.blas import blas_info

__all__ = [
    "FORMAT",
    "FORMAT_INPUTS_ONLY",
    "METADATA_NAME",
    "SessionInfo",
    "git_commit",
    "package_versions",
    "session_metadata",
]

#: Name of the metadata record in every file.
METADATA_NAME = "roger.session"
#: Value of the ``format`` key: bump when the meaning of the log changes. Version 2: the log
#: holds the daemon's decision records (``roger/<robot>/daemon/*``, :mod:`protocols.decisions`),
#: which replay and recovery read; version 1 (older daemons, ``roger record``, files without
#: decisions): only what was received and published, so the learned pairs are re-derived.
FORMAT = "roger-session/2"
FORMAT_INPUTS_ONLY = "roger-session/1"

_DISTRIBUTIONS = {
    "roger": "roger",
    "numpy": "numpy",
    "scipy": "scipy",
    "zenoh": "eclipse-zenoh",
    "mcap": "mcap",
    "msgpack": "msgpack",
}


def package_versions() -> dict[str, str]:
    """``{"<name>_version": version}`` for roger, numpy, scipy, zenoh, mcap, msgpack, python.

    Read from the installed distributions' metadata, so nothing heavy (zenoh) is imported.
    """
    out: dict[str, str] = {}
    for name, dist in _DISTRIBUTIONS.items():
        try:
            out[f"{name}_version"] = importlib_metadata.version(dist)
        except importlib_metadata.PackageNotFoundError:
            out[f"{name}_version"] = ""
    if not out["roger_version"]:
        from roger_daemon import __version__

        out["roger_version"] = __version__
    out["python_version"] = platform.python_version()
    return out


def git_commit() -> str:
    """The project's git commit if it runs from a checkout (read from ``.git``, no subprocess)."""
    root = Path(__file__).resolve().parents[2]
    git = root / ".git"
    try:
        head = (git / "HEAD").read_text().strip()
        if not head.startswith("ref: "):
            return head
        ref = head[5:]
        ref_file = git / ref
        if ref_file.is_file():
            return ref_file.read_text().strip()
        packed = git / "packed-refs"
        if packed.is_file():
            for line in packed.read_text().splitlines():
                parts = line.split()
                if len(parts) == 2 and parts[1] == ref:
                    return parts[0]
    except OSError:
        pass
    return ""


def _params_json(params: Any) -> str:
    if params is None:
        return ""
    if hasattr(params, "to_mapping"):
        params = params.to_mapping()
    if not isinstance(params, Mapping):
        raise TypeError(f"learner_params must be a mapping or have to_mapping(), got {params!r}")
    return json.dumps(dict(params), sort_keys=True, allow_nan=False)


def session_metadata(
    *,
    robot: str,
    config_text: str = "",
    learner_params: Any = None,
    dims: Dims | tuple[int, int] | None = None,
    seed: int | None = None,
    model: str = "roger",
    mode: str = "learn+predict",
    start_updates: int = 0,
    checkpoint: str = "",
    pair_window: int | None = None,
    queue_size: int | None = None,
    restored_queued_pairs: int = 0,
    resumed_session: str | None = None,
    resumed_segment: int = 0,
    created_by: str = "roger daemon",
    decisions: bool = False,
    start_model_digest: str = "",
    extra: Mapping[str, str] | None = None,
) -> dict[str, str]:
    """Build the ``roger.session`` metadata map (all values are strings).

    Parameters
    ----------
    robot
        The robot this session is for.
    config_text
        The daemon's config file, verbatim (TOML).
    learner_params
        A ``RogerParams`` (anything with ``to_mapping()``) or a mapping; stored as sorted JSON.
    dims
        Perception and action sizes.
    seed
        The model's integer seed.
    model
        ``"roger"`` or ``"unimap"`` (the baseline).
    mode
        The daemon's mode at the start of the session (replay applies later ``control`` messages).
    start_updates
        ``model.n_learned`` when the session starts: 0 for a fresh model, the checkpoint's count
        when the daemon resumed from a checkpoint.
    checkpoint
        The checkpoint the model was restored from, if any.
    pair_window, queue_size
        The daemon's pairing window and training-queue size (replay pairs with the same window;
        default 64 when absent).
    restored_queued_pairs
        Pairs the checkpoint held unlearned (its training queue): the model learns them first,
        before any pair of this session, so this session's pairs start at index
        ``start_updates + restored_queued_pairs``.
    resumed_session, resumed_segment
        Where in the history the checkpoint was taken: the session id (and the segment, i.e.
        the number of resets before it in that session) stored in the checkpoint's metadata.
        ``""`` for a fresh model, or for a checkpoint that does not say; ``None`` leaves the
        keys out. Log-tail catch-up follows this chain to tell which sessions continue which.
    created_by
        Which program wrote the file.
    decisions
        The writer records the daemon's decisions (format :data:`FORMAT`, version 2); else
        the file holds inputs and outputs only (:data:`FORMAT_INPUTS_ONLY`, version 1).
    start_model_digest
        SHA-256 of the arrays of the model the session starts with
        (``roger_daemon.daemon.checkpoint.array_digest``): the first link of the chain of the
        checkpoints' model digests in the decision records, which replay checks.
    extra
        More string keys (they must not collide with the standard ones).
    """
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    if isinstance(dims, tuple):
        dims = Dims(*dims)
    out: dict[str, str] = {
        "format": FORMAT if decisions else FORMAT_INPUTS_ONLY,
        "robot": robot,
        "created_by": created_by,
        "config": config_text,
        "learner_params": _params_json(learner_params),
        "dims": json.dumps({"x": dims.x, "y": dims.y}) if dims is not None else "",
        "seed": "" if seed is None else str(int(seed)),
        "model": model,
        "mode": mode,
        "start_updates": str(int(start_updates)),
        "checkpoint": checkpoint,
        "pair_window": "" if pair_window is None else str(int(pair_window)),
        "queue_size": "" if queue_size is None else str(int(queue_size)),
        "restored_queued_pairs": str(int(restored_queued_pairs)),
        "start_model_digest": start_model_digest,
        "hostname": socket.gethostname(),
        "platform": platform.platform(),
        "git_commit": git_commit(),
        "blas": json.dumps(blas_info(), sort_keys=True),
        **package_versions(),
    }
    if resumed_session is not None:
        out["resumed_session"] = resumed_session
        out["resumed_segment"] = str(int(resumed_segment))
    for k, v in (extra or {}).items():
        if k in out:
            raise ValueError(f"extra metadata key {k!r} collides with a standard key")
        out[str(k)] = str(v)
    return out


def _pair_window(meta: Mapping[str, str]) -> int | None:
    """``pair_window`` from the metadata, else from the recorded config's ``[daemon]`` table
    (read by the daemon's own parser: :func:`roger_daemon.config.daemon_settings`)."""
    txt = meta.get("pair_window", "")
    if txt:
        return int(txt)
    config = meta.get("config", "")
    if not config:
        return None
    from roger_daemon.config import ConfigError, daemon_settings

    try:
        return int(daemon_settings(config)["pair_window"])
    except ConfigError:
        return None


@dataclass(frozen=True)
class SessionInfo:
    """The replay-relevant part of a ``roger.session`` record, parsed."""

    robot: str
    dims: Dims | None
    seed: int | None
    learner_params: dict[str, Any] | None
    model: str
    mode: str
    start_updates: int
    pair_window: int | None
    session_id: str
    part: int
    raw: dict[str, str]
    restored_queued_pairs: int = 0
    resumed_session: str | None = None  # None: the log predates the key
    resumed_segment: int = 0
    checkpoint: str = ""
    format_version: int = 1

    @property
    def decisions(self) -> bool:
        """The log holds the daemon's decision records (format version 2 or later)."""
        return self.format_version >= 2

    def profile(self) -> Any:
        """The robot profile of the log (:mod:`roger_daemon.profiles`): the one its metadata
        records (``robot_profile``), else the shipped profile of its dims, else generic names.
        """
        from roger_daemon.profiles import (
            ProfileError,
            RobotProfile,
            generic_profile,
            profile_for_dims,
        )

        text = self.raw.get("robot_profile", "")
        if text:
            try:
                return RobotProfile.from_mapping(json.loads(text))
            except (ValueError, ProfileError):
                pass  # an unreadable record: the log's dims still name the fields
        if self.dims is None:
            return generic_profile(Dims(0, 0))
        return profile_for_dims(self.dims)

    @property
    def fresh(self) -> bool:
        """The session started from a fresh model (no checkpoint)."""
        return self.start_updates == 0 and not self.checkpoint and not self.restored_queued_pairs

    @classmethod
    def from_metadata(cls, meta: Mapping[str, str]) -> SessionInfo:
        """Parse a metadata map; missing keys (``roger record`` files) become None/defaults."""
        dims_txt = meta.get("dims", "")
        dims = None
        if dims_txt:
            d = json.loads(dims_txt)
            dims = Dims(int(d["x"]), int(d["y"]))
        params_txt = meta.get("learner_params", "")
        params = json.loads(params_txt) if params_txt else None
        if params is not None and not isinstance(params, dict):
            raise ValueError("metadata learner_params is not a JSON object")
        seed_txt = meta.get("seed", "")
        mode = meta.get("mode", "") or "learn+predict"
        return cls(
            robot=meta.get("robot", ""),
            dims=dims,
            seed=int(seed_txt) if seed_txt else None,
            learner_params=params,
            model=meta.get("model", "") or "roger",
            mode=mode if mode in MODES else "learn+predict",
            start_updates=int(meta.get("start_updates", "") or 0),
            pair_window=_pair_window(meta),
            session_id=meta.get("session_id", ""),
            part=int(meta.get("part", "") or 0),
            raw=dict(meta),
            restored_queued_pairs=int(meta.get("restored_queued_pairs", "") or 0),
            resumed_session=meta.get("resumed_session"),
            resumed_segment=int(meta.get("resumed_segment", "") or 0),
            checkpoint=meta.get("checkpoint", ""),
            format_version=_format_version(meta.get("format", "")),
        )


def _format_version(text: str) -> int:
    """N of ``roger-session/N`` (1 when absent or unreadable: the oldest logs)."""
    _, _, n = text.partition("/")
    return int(n) if n.isdigit() else 1
