"""How the learner's kernels are compiled (:mod:`.jit_kernels`, :mod:`.jit_particles`, ...).

numba's on-disk cache checks only the source file of the function it loads: a kernel that
calls (and inlines) kernels of another module keeps running the old callee after that module
changes (numba documents this limitation).  So the cache is tied to all the kernel modules at
once: :func:`compiled` keeps a fingerprint of their sources in the cache directory, and where
it does not match, drops the entries of these modules before the first one is loaded
(docs/performance.md, *numba's cache*).  The kernels are compiled for one CPU model on every
x86-64 host that can run its code (:mod:`.jit_target`), not for the host's own.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar, cast

from numba import njit

from roger_daemon.learner.engine.jit_target import pin

pin()  # before the first kernel is decorated: one CPU model's code on every host (.jit_target)

__all__ = ["FINGERPRINT_FILE", "cache_dir", "compiled", "source_fingerprint"]

F = TypeVar("F", bound=Callable[..., Any])

#: in numba's cache directory: the :func:`source_fingerprint` its kernel entries were built from
FINGERPRINT_FILE = "roger-kernels.sha256"
#: the modules whose kernels are compiled here (their cache entries are ``jit_*``), and
#: :mod:`.jit`, whose constants they compile in
_MODULES = ("jit.py", "jit_*.py")
_checked: set[str] = set()  # cache directories checked by this process


def source_fingerprint(folder: Path | None = None) -> str:
    """SHA-256 of the kernel modules' names and sources (``jit.py``, ``jit_*.py`` of the
    learner, or of ``folder``)."""
    where = folder or Path(__file__).parent
    digest = hashlib.sha256()
    for path in sorted(p for pattern in _MODULES for p in where.glob(pattern)):
        digest.update(path.name.encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()


def drop_stale_entries(cache_dir: Path, fingerprint: str) -> bool:
    """Remove the kernel modules' entries from numba's ``cache_dir`` unless they were built
    from the sources ``fingerprint`` names, then record it; ``True`` if entries were dropped.
    Only files numba wrote for these modules (``jit_*.nbi``, ``jit_*.nbc``) are removed; an
    unwritable directory is left as it is."""
    stamp = cache_dir / FINGERPRINT_FILE
    try:
        if stamp.read_text(encoding="ascii").strip() == fingerprint:
            return False
    except (OSError, UnicodeDecodeError):
        pass
    dropped = False
    try:
        for pattern in ("jit_*.nbi", "jit_*.nbc"):
            for entry in cache_dir.glob(pattern):
                entry.unlink(missing_ok=True)
                dropped = True
        cache_dir.mkdir(parents=True, exist_ok=True)
        part = cache_dir / f"{FINGERPRINT_FILE}.{os.getpid()}"
        part.write_text(fingerprint + "\n", encoding="ascii")
        part.replace(stamp)  # atomic: a process starting beside this one reads all or nothing
    except OSError:
        pass
    return dropped


def cache_dir(kernel: Any) -> str | None:
    """The directory of numba's on-disk cache that ``kernel`` (a :func:`compiled` function)
    loads from and writes to; ``None`` where it has none (numba's ``NullCache``)."""
    where: str | None = getattr(getattr(kernel, "_cache", None), "cache_path", None)
    return where


def compiled(**options: Any) -> Callable[[F], F]:
    """``numba.njit(cache=True, **options)``, with the cache checked against the kernel
    sources (module docstring); without the on-disk cache where no cache directory is writable
    (a read-only install with no usable home: numba then refuses ``cache=True`` when
    decorating), so the kernels are compiled in every process instead.  A hardened service
    sets ``NUMBA_CACHE_DIR`` to a writable path (configs/systemd)."""

    def wrap(fn: F) -> F:
        try:
            dispatcher = njit(cache=True, **options)(fn)
        except RuntimeError:  # "cannot cache function ...: no locator available"
            return cast(F, njit(**options)(fn))
        where = cache_dir(dispatcher)
        if where is not None and where not in _checked:
            _checked.add(where)
            drop_stale_entries(Path(where), source_fingerprint())
        return cast(F, dispatcher)

    return wrap
