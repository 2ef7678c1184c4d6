"""One BLAS thread wherever the learner runs, and a record of which BLAS computed.

The learner's floats depend on how a BLAS kernel splits and orders its sums: a different
thread count (or another CPU kernel, ``OPENBLAS_CORETYPE``) gives results that differ in the
last bits. With one thread, one machine and one kernel the learner is bit-for-bit repeatable;
across kernels the structure is the same and the floats agree within the tolerance documented
in ``docs/reproducibility.md``. Every ``roger`` command pins the thread count here, at start-up
(:func:`roger_daemon.cli.main`), and so does the test suite (``tests/conftest.py``): one owner,
whatever the calling shell's ``OPENBLAS_NUM_THREADS`` says. A program that imports the learner
as a library calls :func:`pin_blas_threads` itself.
"""

from __future__ import annotations

from typing import Any

__all__ = ["blas_info", "pin_blas_threads"]

_limiter: Any = None  # kept alive: the limits hold while it exists


def pin_blas_threads(threads: int = 1) -> None:
    """Limit every BLAS/OpenMP library loaded now or by numpy/scipy to ``threads`` threads.

    Imports numpy and ``scipy.linalg`` first so that both OpenBLAS copies (numpy's and
    scipy's) are loaded and limited. Idempotent.
    """
    global _limiter
    import numpy  # noqa: F401 - load the libraries threadpoolctl limits
    import scipy.linalg  # noqa: F401
    from threadpoolctl import threadpool_limits

    _limiter = threadpool_limits(limits=threads)


def blas_info() -> list[dict[str, Any]]:
    """The BLAS libraries in this process: library, version, kernel and thread count.

    JSON-ready; recorded in the session metadata of every MCAP log and in the experiment's
    ``results.json`` so a float difference between two runs can be traced to its kernel.
    """
    from threadpoolctl import threadpool_info

    return [
        {
            "library": str(p.get("internal_api", "")),
            "version": str(p.get("version", "")),
            "kernel": str(p.get("architecture", "")),
            "threads": int(p.get("num_threads", 0)),
            "file": str(p.get("filepath", "")).rsplit("/", 1)[-1],
        }
        for p in threadpool_info()
        if p.get("user_api") == "blas"
    ]
