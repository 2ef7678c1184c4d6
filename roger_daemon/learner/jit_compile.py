"""How the learner's kernels are compiled (:mod:`.jit_kernels`, :mod:`.jit_particles`)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar, cast

from numba import njit

__all__ = ["compiled"]

F = TypeVar("F", bound=Callable[..., Any])


def compiled(**options: Any) -> Callable[[F], F]:
    """``numba.njit(cache=True, **options)``; without the on-disk cache where no cache
    directory is writable (a read-only install with no usable home: numba then refuses
    ``cache=True`` when decorating), so the kernels are compiled in every process instead.
    A hardened service sets ``NUMBA_CACHE_DIR`` to a writable path (configs/systemd)."""

    def wrap(fn: F) -> F:
        try:
            return cast(F, njit(cache=True, **options)(fn))
        except RuntimeError:  # "cannot cache function ...: no locator available"
            return cast(F, njit(**options)(fn))

    return wrap
