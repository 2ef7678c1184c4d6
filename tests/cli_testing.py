"""``roger ARGV`` run in the test's own process, for the tests of a command's exit status and
messages: :func:`roger_daemon.cli.main`, the command line's code path, without a second
interpreter's start-up (~1-2 s of CPU each: imports and the learner's kernels; docs/testing.md,
*Keeping it*). A traceback fails the test here instead of reaching stderr. What a command sets
for its process is restored after it: the working directory and the root logger's handlers
(``roger_daemon.console.configure_logging``)."""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import pytest

from roger_daemon.cli import main

__all__ = ["Ran", "in_process"]


@dataclass
class Ran:
    """What ``roger ARGV`` did: its exit status and what it wrote."""

    returncode: int
    stdout: str
    stderr: str


@contextmanager
def in_process(capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
               ) -> Iterator[Callable[..., Ran]]:
    """``with in_process(capsys, monkeypatch) as run``: ``run(*argv, cwd=None) -> Ran``."""

    def run(*argv: str, cwd: Path | None = None) -> Ran:
        if cwd is not None:
            monkeypatch.chdir(cwd)
        capsys.readouterr()
        try:
            code = main(list(argv))
        except SystemExit as exc:  # argparse's usage errors
            code = int(exc.code or 0)
        out = capsys.readouterr()
        return Ran(code, out.out, out.err)

    root = logging.getLogger()
    handlers, level = list(root.handlers), root.level
    try:
        yield run
    finally:
        root.handlers[:] = handlers
        root.setLevel(level)
