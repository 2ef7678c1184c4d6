"""Test-suite set-up shared by every test module."""

from __future__ import annotations

from roger_daemon.blas import pin_blas_threads

# The learner runs with one BLAS thread wherever it runs (roger_daemon/blas.py); tests that
# learn in-process get the same pinning as every `roger` command, whatever the shell says.
pin_blas_threads(1)
