"""Retention: the daemon's files stay within a byte budget and an age limit.

One rule for both kinds of files the daemon accumulates: the oldest go first, while the total
is over ``max_bytes`` or while they are older than ``max_age_s`` (by modification time); a
limit of 0 means none. What is still needed is never deleted: the newest checkpoint of a
robot, and the session file being written. ``[checkpoint]`` and ``[recording]`` in the daemon's
TOML set the limits (``max_bytes``, ``max_age_days``).

- Checkpoints (:func:`prune_checkpoints`, after every checkpoint written): the ``keep`` count
  applies first, then the limits.
- Recordings (:func:`prune_recordings`, at start-up and once a minute): session files of one
  robot (``roger-<robot>-*.mcap`` and their ``.damaged`` originals), oldest file first. A
  deleted part makes the start of its session unreplayable; the write-ahead log, not the
  recordings, is what start-up recovery needs.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterable, Sequence
from pathlib import Path

__all__ = ["prune_checkpoints", "prune_oldest", "prune_recordings"]

log = logging.getLogger(__name__)


def prune_oldest(files: Sequence[Path], *, max_bytes: int = 0, max_age_s: float = 0.0,
                 keep: Iterable[Path] = (), now: float | None = None) -> list[Path]:
    """Delete from ``files`` (oldest first) until the limits hold; return what was deleted.

    Files in ``keep`` are never deleted but count towards ``max_bytes``.
    """
    now = time.time() if now is None else now
    kept = {Path(p) for p in keep}
    stats = []
    for p in files:
        try:
            st = p.stat()
        except FileNotFoundError:
            continue
        stats.append((p, st.st_size, st.st_mtime))
    total = sum(size for _, size, _ in stats)
    gone = []
    for p, size, mtime in stats:
        too_big = max_bytes > 0 and total > max_bytes
        too_old = max_age_s > 0 and now - mtime > max_age_s
        if p in kept or not (too_big or too_old):
            continue
        try:
            p.unlink()
        except OSError as exc:
            log.warning("retention: could not delete %s: %s", p, exc)
            continue
        total -= size
        gone.append(p)
    return gone


def prune_checkpoints(newest_first: Sequence[Path], *, keep: int, max_bytes: int = 0,
                      max_age_s: float = 0.0) -> list[Path]:
    """Apply ``keep`` then the limits to one robot's checkpoints (newest first)."""
    gone = []
    for old in newest_first[keep:]:
        try:
            old.unlink()
            gone.append(old)
        except OSError as exc:
            log.warning("could not remove old checkpoint %s: %s", old, exc)
    rest = list(reversed(newest_first[:keep]))  # oldest first
    if rest:
        gone += prune_oldest(rest, max_bytes=max_bytes, max_age_s=max_age_s, keep=rest[-1:])
    return gone


def prune_recordings(directory: Path, robot: str, *, max_bytes: int = 0, max_age_s: float = 0.0,
                     keep: Iterable[Path] = ()) -> list[Path]:
    """Apply the limits to one robot's session files in ``directory`` (oldest first)."""
    if max_bytes <= 0 and max_age_s <= 0:
        return []
    from roger_daemon.recording.files import list_session_files

    files: list[Path] = []
    for sf in list_session_files(directory, robot=robot):
        files.append(sf.path)
        files.extend(sorted(sf.path.parent.glob(sf.path.name + ".damaged*")))
    gone = prune_oldest(files, max_bytes=max_bytes, max_age_s=max_age_s, keep=keep)
    if gone:
        log.info("%s: retention deleted %d recording file(s) (oldest %s)", robot, len(gone),
                 gone[0].name)
    return gone
