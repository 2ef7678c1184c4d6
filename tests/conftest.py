"""Test-suite set-up shared by every test module."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from roger_daemon.blas import pin_blas_threads

# The learner runs with one BLAS thread wherever it runs (roger_daemon/blas.py); tests that
# learn in-process get the same pinning as every `roger` command, whatever the shell says.
pin_blas_threads(1)


@pytest.fixture(autouse=True)
def _restore_learner_threads() -> Iterator[None]:
    """A test that sets the learner's thread count (``jit.set_threads``) gets it reset after."""
    from roger_daemon.learner.engine import jit, jit_threads

    before = jit_threads._threads
    yield
    if jit_threads._threads != before:
        jit.set_threads(before)


@pytest.fixture(scope="session", autouse=True)
def _learner_kernels_compiled() -> None:
    """Compile the learner's kernels into numba's on-disk cache before the first test (each
    test process does; it took ~45 s on a 2-core AMD EPYC from a clean clone): the daemons,
    workers and commands the tests start then load them instead of compiling them inside
    their start-up deadlines."""
    from roger_daemon.learner.engine import jit

    jit.warm_up()
