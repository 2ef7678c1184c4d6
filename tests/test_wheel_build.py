"""An in-tree wheel build leaves the source tree as it was (issue 56, rough edge 20).

setuptools' own backend writes ``build/`` and ``roger.egg-info`` beside ``pyproject.toml``;
the package's backend (``build_backend/roger_build.py``) sends both to a temporary directory.
The build runs on a copy of the tracked tree, offline (``--no-build-isolation``: the test
extra brings setuptools 77 or later), and the licence deprecation warning of older
``project.license`` tables must not appear in its log.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NOT_COPIED = {".git", ".venv", ".venv-peers", "build", "dist", "runs", "out", "__pycache__",
              ".pytest_cache", ".mypy_cache", ".ruff_cache", ".hypothesis"}


def _tree(top: Path) -> set[str]:
    return {str(path.relative_to(top)) for path in top.rglob("*")}


def _copy_of_the_source(dest: Path) -> Path:
    def ignore(_: str, names: list[str]) -> set[str]:
        return {n for n in names if n in NOT_COPIED or n.endswith(".egg-info")}
    shutil.copytree(ROOT, dest, symlinks=True, ignore=ignore)
    return dest


@pytest.mark.integration
def test_pip_wheel_in_the_tree_writes_no_build_directory(tmp_path: Path) -> None:
    source = _copy_of_the_source(tmp_path / "src")
    before = _tree(source)
    out = tmp_path / "wheels"
    env = {**os.environ, "PIP_NO_INDEX": "1", "PYTHONWARNINGS": "always"}
    env.pop("DIST_EXTRA_CONFIG", None)
    done = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", ".", "--no-deps", "--no-build-isolation",
         "-v", "-w", str(out)], cwd=source, capture_output=True, text=True, timeout=240,
        env=env)
    log = done.stdout + done.stderr
    assert done.returncode == 0, log[-3000:]
    assert _tree(source) == before  # no build/, no roger.egg-info, nothing else
    (wheel,) = out.glob("roger-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    assert "roger_daemon/configs/robots/aibo.toml" in names
    assert any(n.endswith(".dist-info/licenses/LICENSE") for n in names)
    assert "License-Expression: MIT" in zipfile.ZipFile(wheel).read(
        next(n for n in names if n.endswith(".dist-info/METADATA"))).decode()
    assert "project.license" not in log and "SetuptoolsDeprecationWarning" not in log


def test_the_backend_is_shipped_in_the_sdist() -> None:
    """``python -m build`` builds the wheel from the sdist, which must carry the backend."""
    manifest = (ROOT / "MANIFEST.in").read_text(encoding="utf-8").split("\n")
    assert "include build_backend/roger_build.py" in manifest
    assert (ROOT / "build_backend" / "roger_build.py").is_file()
