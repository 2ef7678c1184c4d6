"""``roger compile``: compile the learner's kernels into numba's on-disk cache, on every core.

The first process that learns after an install, an upgrade or a change to a kernel's source
compiles the kernels (about a minute on a 2-core machine) unless they are in numba's cache.
This fills the cache ahead of time, in ``--processes`` processes at once, each compiling a
share of the kernel families (:mod:`roger_daemon.learner.engine.jit_warm`); with a warm cache
it only checks it.  ``make test`` and ``make demo`` run it first; after an upgrade of a service, run
it as the service's user with its ``NUMBA_CACHE_DIR`` (the systemd unit's) before the restart.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time

from roger_daemon.console import require

__all__ = ["configure", "run"]


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``roger compile``."""
    parser.add_argument("--processes", type=int, default=None, metavar="N",
                        help="compiling processes (default: the usable cores, at most one per "
                             "kernel family)")
    parser.add_argument("--share", default=None, help=argparse.SUPPRESS)  # one process's part


def _share(text: str) -> tuple[int, int]:
    parts = text.split("/")
    ok = len(parts) == 2 and all(p.isdigit() for p in parts) and int(parts[0]) < int(parts[1])
    require(ok, "--share", "I/N with 0 <= I < N", text)
    return int(parts[0]), int(parts[1])


def run(args: argparse.Namespace) -> int:
    """Compile every kernel family in ``--processes`` child processes (or, with the internal
    ``--share I/N``, this process's share); exit 1 if a child failed."""
    from roger_daemon.fsm import jit_fsm
    from roger_daemon.learner.engine.jit_warm import ALSO_WITH_THE_REST, WARMERS, warm

    if args.share is not None:
        if jit_fsm.warm not in ALSO_WITH_THE_REST:  # the learned transitions' kernels
            ALSO_WITH_THE_REST.append(jit_fsm.warm)
        warm(*_share(args.share))
        return 0
    require(args.processes is None or args.processes >= 1, "--processes", "an integer >= 1",
            args.processes)
    from roger_daemon.learner.engine import jit_batch
    from roger_daemon.learner.engine.jit_compile import cache_dir

    where = cache_dir(jit_batch.terms_batch)
    if where is None:
        print("roger compile: numba has no writable cache directory here, so every process "
              "compiles the kernels again; set NUMBA_CACHE_DIR to a writable directory",
              file=sys.stderr)
        return 1
    from roger_daemon.machine import usable_cores

    n = min(args.processes or usable_cores(), len(WARMERS))
    t0 = time.monotonic()
    procs = [subprocess.Popen([sys.executable, "-m", "roger_daemon", "compile", "--share",
                               f"{i}/{n}"]) for i in range(n)]
    failed = [i for i, p in enumerate(procs) if p.wait() != 0]
    if failed:
        print(f"roger compile: share(s) {failed} of {n} failed (their errors are above)",
              file=sys.stderr)
        return 1
    print(f"learner kernels in numba's cache ({where}): compiled, or found there, by {n} "
          f"processes in {time.monotonic() - t0:.1f} s")
    return 0
