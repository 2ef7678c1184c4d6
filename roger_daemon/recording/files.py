"""Session file names: ``roger-<robot>-<UTC start>[_k][-NNN].mcap``.

* ``<UTC start>`` is ``YYYYMMDDTHHMMSSZ``; ``_k`` (k >= 2) disambiguates two sessions of one robot
  started within the same second; ``-NNN`` (001, 002, ...) numbers rotated parts after the first.
* The session id is the name without part and extension: ``roger-aibo-20261121T235900Z``.

Lexical order of the names is not session order (``-001.mcap`` sorts before ``.mcap``), so use
:func:`list_session_files`, which sorts by (start, k, part).
"""

from __future__ import annotations

import re
import time
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from roger_daemon.recording.mcapio import read_metadata

__all__ = [
    "SessionFile",
    "group_sessions",
    "list_session_files",
    "parse_name",
    "part_path",
    "session_id_for",
    "session_id_of",
    "session_order",
    "sessions",
]

_NAME = re.compile(
    r"^(?P<sid>roger-(?P<robot>[A-Za-z0-9_\-]{1,64})-(?P<stamp>\d{8}T\d{6}Z)(?:_(?P<k>\d+))?)"
    r"(?:-(?P<part>\d{3,}))?\.mcap$"
)


@dataclass(frozen=True, order=True)
class SessionFile:
    """One file of a session, sortable in recording order."""

    stamp: str
    k: int
    part: int
    robot: str
    session_id: str
    path: Path


def parse_name(path: str | Path) -> SessionFile | None:
    """The parts of a session file name, or None if the name is not one."""
    p = Path(path)
    m = _NAME.match(p.name)
    if not m:
        return None
    return SessionFile(
        stamp=m["stamp"],
        k=int(m["k"] or 1),
        part=int(m["part"] or 0),
        robot=m["robot"],
        session_id=m["sid"],
        path=p,
    )


def _stamp(start_ns: int) -> str:
    return time.strftime("%Y%m%dT%H%M%SZ", time.gmtime(start_ns // 1_000_000_000))


def session_id_for(directory: Path, robot: str, start_ns: int) -> str:
    """A session id for ``robot`` started at ``start_ns`` that no file in ``directory`` uses."""
    base = f"roger-{robot}-{_stamp(start_ns)}"
    taken = {sf.session_id for sf in list_session_files(directory, robot=robot)}
    if base not in taken:
        return base
    k = 2
    while f"{base}_{k}" in taken:
        k += 1
    return f"{base}_{k}"


def part_path(directory: Path, session_id: str, part: int) -> Path:
    """Path of part ``part`` (0 = the first file) of a session."""
    suffix = "" if part == 0 else f"-{part:03d}"
    return directory / f"{session_id}{suffix}.mcap"


def list_session_files(directory: str | Path, robot: str | None = None) -> list[SessionFile]:
    """Every session file in ``directory`` (not recursive), oldest session first, parts in order."""
    d = Path(directory)
    if not d.is_dir():
        return []
    out = []
    for p in d.iterdir():
        sf = parse_name(p)
        if sf is not None and (robot is None or sf.robot == robot) and p.is_file():
            out.append(sf)
    return sorted(out)


def group_sessions(files: list[SessionFile]) -> list[list[SessionFile]]:
    """Group sorted session files by session id, keeping order."""
    groups: dict[str, list[SessionFile]] = {}
    for sf in sorted(files):
        groups.setdefault(sf.session_id, []).append(sf)
    return list(groups.values())


def sessions(source: str | Path | Iterable[str | Path], robot: str | None) -> list[list[Path]]:
    """The sessions in ``source`` (a directory, or files), each its parts in order.

    Files named otherwise are grouped by the session id in their metadata, in the given order.
    """
    if isinstance(source, str | Path) and Path(source).is_dir():
        found = list_session_files(source, robot=robot)
        return [[sf.path for sf in g] for g in group_sessions(found)]
    paths = [Path(source)] if isinstance(source, str | Path) else [Path(p) for p in source]
    parsed = [parse_name(p) for p in paths]
    if all(sf is not None for sf in parsed):
        return [[sf.path for sf in g] for g in group_sessions(
            [sf for sf in parsed if sf is not None])]
    # Unnamed files: group by the session id in their metadata, keeping the given order.
    groups: dict[str, list[Path]] = {}
    for p in paths:
        try:
            sid = read_metadata(p).get("session_id", "") or str(p)
        except Exception:
            sid = str(p)
        groups.setdefault(sid, []).append(p)
    return list(groups.values())


def session_id_of(path: Path) -> str:
    """The session id of a file: from its name, else its metadata, else its path."""
    sf = parse_name(path)
    if sf is not None:
        return sf.session_id
    try:
        return read_metadata(path).get("session_id", "") or str(path)
    except Exception:
        return str(path)


def session_order(session_id: str) -> tuple[str, int] | None:
    """The key that sorts session ids in start order (``None`` for an unnamed session)."""
    sf = parse_name(session_id + ".mcap")
    return None if sf is None else (sf.stamp, sf.k)
