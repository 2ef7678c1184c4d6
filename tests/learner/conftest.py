"""Fixtures shared by the learner's batched-kernel tests."""

from __future__ import annotations

import pytest

from roger_daemon.learner.engine import jit_threads


@pytest.fixture
def batch_every_size(monkeypatch: pytest.MonkeyPatch) -> None:
    """The experts in these tests are small: batch them whatever their size (on as many
    threads as :func:`roger_daemon.learner.engine.jit.set_threads` gives)."""
    monkeypatch.setattr(jit_threads, "BATCH_MIN_ENTRIES", 0)
