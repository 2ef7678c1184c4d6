"""Keep the daemon's resident memory flat: large transient buffers go back to the system.

A checkpoint moves the whole model state through memory a few times (the worker's
``state_dict`` and its msgpack frame, the loop's copy for the writer thread). glibc's malloc
raises its mmap threshold dynamically each time such a block is freed (up to 32 MB on 64-bit),
so later blocks of that size come from the heap, and a heap fragmented by small objects keeps
them: the resident size grew with every checkpoint (``roger bench soak``, docs/fleet.md).
Fixing the threshold (``mallopt(M_MMAP_THRESHOLD)``, which also switches the dynamic rule off)
serves every block of 128 KiB or more from its own mapping, returned to the system when freed.
Nothing happens where glibc is not the C library.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging

__all__ = ["limit_heap_growth"]

log = logging.getLogger(__name__)

_M_MMAP_THRESHOLD = -3


def limit_heap_growth(threshold: int = 128 * 1024) -> bool:
    """Serve allocations of ``threshold`` bytes or more by ``mmap`` (fixed; glibc only).

    Returns True if the setting took effect."""
    name = ctypes.util.find_library("c")
    if not name:
        return False
    try:
        libc = ctypes.CDLL(name)
        ok = int(libc.mallopt(_M_MMAP_THRESHOLD, int(threshold)))
    except (OSError, AttributeError):
        return False
    if ok != 1:
        log.debug("mallopt(M_MMAP_THRESHOLD) refused")
    return ok == 1
