"""``roger compile``: numba's cache of the learner's kernels filled by several processes."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from roger_daemon.learner.engine.jit_warm import WARMERS, shares

ROOT = Path(__file__).resolve().parents[1]

_MISSES = """
import json
import roger_daemon.learner.engine.jit as jit
jit.warm_up()
kernels = [getattr(jit, name) for name in jit.KERNELS]
print(json.dumps({"misses": sum(sum(k.stats.cache_misses.values()) for k in kernels),
                  "hits": sum(sum(k.stats.cache_hits.values()) for k in kernels)}))
"""


@pytest.mark.parametrize("of", [1, 2, 3, 4, 6])
def test_the_shares_split_the_families_once_each(of: int) -> None:
    got = shares(of)
    assert len(got) == of
    flat = [w for share in got for w in share]
    assert sorted(flat, key=id) == sorted((w for w, _ in WARMERS), key=id)
    assert sum(1 for share in got if share) == min(of, len(WARMERS))


def test_two_shares_put_the_costliest_family_alone() -> None:
    first, second = shares(2)
    costliest = max(WARMERS, key=lambda w: w[1])[0]
    assert first == [costliest] and costliest not in second


def _roger(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "roger_daemon", *args], capture_output=True,
                          text=True, cwd=ROOT, timeout=600, env=env)


@pytest.mark.parametrize(("args", "message"), [
    (["--processes", "0"], "--processes must be an integer >= 1, got 0"),
    (["--share", "2/2"], "--share must be I/N with 0 <= I < N, got '2/2'"),
    (["--share", "x"], "--share must be I/N with 0 <= I < N, got 'x'"),
])
def test_bad_arguments_exit_2_naming_them(args: list[str], message: str,
                                          capsys: pytest.CaptureFixture[str],
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """In this process (the command's code path without an interpreter's start-up; a
    traceback would fail the test here), with what the command sets restored after it: the
    warmers it adds and its logging handler."""
    import logging

    from roger_daemon.cli import main
    from roger_daemon.learner.engine import jit_warm

    monkeypatch.setattr(jit_warm, "ALSO_WITH_THE_REST", list(jit_warm.ALSO_WITH_THE_REST))
    root = logging.getLogger()
    handlers, level = list(root.handlers), root.level
    try:
        assert main(["compile", *args]) == 2
    finally:
        root.handlers[:], root.level = handlers, level
    assert message in capsys.readouterr().err


def test_with_the_cache_filled_it_reports_and_exits_0() -> None:
    """The suite's processes share numba's cache (``conftest`` warms it up first)."""
    out = _roger("compile", "--processes", "2")
    assert out.returncode == 0, out.stderr
    assert "learner kernels in numba's cache (" in out.stdout
    assert "found there, by 2 processes" in out.stdout


@pytest.mark.slow
def test_on_an_empty_cache_it_compiles_what_warm_up_needs(tmp_path: Path) -> None:
    """Oracle: numba's own cache statistics. After ``roger compile`` into an empty cache, a
    fresh process's ``warm_up`` loads every kernel and compiles none."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    out = _roger("compile", env=env)
    assert out.returncode == 0, out.stderr
    assert str(tmp_path / "cache") in out.stdout
    probe = subprocess.run([sys.executable, "-c", _MISSES], capture_output=True, text=True,
                           cwd=ROOT, timeout=600, env=env, check=True)
    got = json.loads(probe.stdout.strip().splitlines()[-1])
    assert got["misses"] == 0 and got["hits"] > 20


def test_without_a_cache_directory_it_says_so_and_exits_1(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """Where numba found no writable cache directory the kernels are compiled without its
    cache (``jit_compile``, a ``NullCache``): compiling ahead would be lost, so it stops first
    (as root the directory cannot be made unwritable, so the kernel is stood in for)."""
    import argparse

    from roger_daemon.learner.engine import jit_batch
    from roger_daemon.tools import compile_kernels

    class Uncached:
        _cache = object()  # numba's NullCache has no cache_path

    monkeypatch.setattr(jit_batch, "terms_batch", Uncached())
    spawned: list[object] = []
    monkeypatch.setattr(compile_kernels.subprocess, "Popen", lambda *a, **k: spawned.append(a))
    code = compile_kernels.run(argparse.Namespace(share=None, processes=2))
    assert code == 1 and spawned == []
    assert "numba has no writable cache directory here" in capsys.readouterr().err
