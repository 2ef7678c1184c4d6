"""The one way ROGER writes a file: atomically and durably.

:func:`atomic_write` yields a temporary file in the destination's directory; when the block
ends without an exception the file is flushed, ``fsync``-ed, renamed over (or, with
``overwrite=False``, linked to) the destination, and the directory is ``fsync``-ed so that the
new name survives a power loss. On an exception the temporary file is removed and the
destination is untouched. A reader therefore sees either the old file or the complete new one,
never a half-written one, whatever happens to the process or the machine.

Every file the daemon, the recording tools and the experiment write whole (checkpoints,
recovered and exported logs, results) goes through here; append-only files (the MCAP session
logs, the write-ahead log) have their own flush/fsync discipline.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

__all__ = [
    "OutputDirError",
    "atomic_write",
    "fsync_dir",
    "owned_output_dir",
    "write_bytes",
    "write_json",
    "write_text",
]


#: the process's umask, read once at import (os.umask can only be read by setting it, which
#: is not safe while other threads create files)
_UMASK = os.umask(0o022)
os.umask(_UMASK)


def fsync_dir(directory: str | Path) -> None:
    """``fsync`` a directory, so that names created or renamed in it are durable."""
    fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextmanager
def atomic_write(path: str | Path, *, overwrite: bool = True) -> Iterator[IO[bytes]]:
    """A binary file that becomes ``path`` atomically and durably when the block succeeds.

    With ``overwrite=False`` an existing ``path`` is never replaced: the commit raises
    :class:`FileExistsError` (checked atomically, by ``os.link``) and the temporary file is
    removed. The parent directory must exist.
    """
    dst = Path(path)
    fd, name = tempfile.mkstemp(prefix=f".{dst.name}.", suffix=".tmp", dir=dst.parent)
    tmp = Path(name)
    try:
        # mkstemp makes the file 0600; the result gets the mode open() would give it
        # (0666 less the umask), as every other file a user's command writes
        os.fchmod(fd, 0o666 & ~_UMASK)
        with os.fdopen(fd, "w+b") as f:  # readable too: h5py and pyarrow may seek and read
            yield f
            f.flush()
            os.fsync(f.fileno())
        if overwrite:
            os.replace(tmp, dst)
        else:
            os.link(tmp, dst)  # fails with FileExistsError if dst exists: no clobbering
            tmp.unlink()
        fsync_dir(dst.parent)
    finally:
        if tmp.exists():
            tmp.unlink()


def write_bytes(path: str | Path, data: bytes, *, overwrite: bool = True) -> None:
    """Write ``data`` to ``path`` with :func:`atomic_write`."""
    with atomic_write(path, overwrite=overwrite) as f:
        f.write(data)


def write_text(path: str | Path, text: str, *, overwrite: bool = True) -> None:
    """Write ``text`` (UTF-8) to ``path`` with :func:`atomic_write`."""
    write_bytes(path, text.encode("utf-8"), overwrite=overwrite)


def write_json(path: str | Path, value: Any, *, indent: int | None = 1,
               default: Any = None, overwrite: bool = True) -> None:
    """Write ``value`` as JSON to ``path`` with :func:`atomic_write`."""
    write_text(path, json.dumps(value, indent=indent, default=default), overwrite=overwrite)


OWNER_MARK = ".roger-output.json"


class OutputDirError(Exception):
    """An output directory the command may not use (the message says why and what to do)."""


@contextmanager
def owned_output_dir(out: str | Path, command: str, *, force: bool = False) -> Iterator[Path]:
    """Use ``out`` as a command's output directory without touching what others put there.

    A missing or empty ``out`` is created and marked (``.roger-output.json``). A directory
    marked by an earlier run of the same ``command`` keeps everything the earlier run did not
    create; what it did create (listed in the mark) is removed first. Any other non-empty
    directory is refused with :class:`OutputDirError` unless ``force`` (then its contents are
    removed). When the block ends, the mark lists every entry created in it.
    """
    import shutil

    d = Path(out)
    if d.exists() and not d.is_dir():
        raise OutputDirError(f"--out {d} exists and is not a directory")
    mark = d / OWNER_MARK
    created: list[str] = []
    if mark.is_file():
        try:
            prev = json.loads(mark.read_text(encoding="utf-8"))
            if prev.get("command") == command:
                created = [str(n) for n in prev.get("created", [])]
        except (ValueError, AttributeError):
            created = []
    others = sorted(p.name for p in d.iterdir() if p.name != OWNER_MARK
                    and p.name not in created) if d.is_dir() else []
    if not mark.is_file() and others and not force:
        raise OutputDirError(
            f"--out {d} is not empty and was not made by `roger {command}` ({len(others)} "
            f"entries, e.g. {others[0]!r}); choose another directory or pass --force to "
            "delete its contents")
    victims = [d / n for n in created] + ([d / n for n in others] if force else [])
    for p in victims:
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p)
        elif p.exists() or p.is_symlink():
            p.unlink()
    d.mkdir(parents=True, exist_ok=True)
    before = {p.name for p in d.iterdir()}
    try:
        yield d
    finally:
        new = sorted({p.name for p in d.iterdir()} - before - {OWNER_MARK})
        write_json(mark, {"command": command, "created": new})
