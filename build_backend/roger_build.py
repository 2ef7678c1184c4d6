"""The package's PEP 517 build backend: setuptools, with its scratch files outside the tree.

setuptools builds a wheel through ``build/`` (``build/lib``, ``build/bdist.*``) and writes
``roger.egg-info`` beside ``pyproject.toml``, so a ``pip wheel .`` from a checkout leaves both
behind. This backend is ``setuptools.build_meta`` with one change: while a wheel or an sdist is
built, setuptools' ``[build] build_base`` and ``[egg_info] egg_base`` point into a temporary
directory, given through ``DIST_EXTRA_CONFIG`` (the extra configuration file that setuptools
reads after ``setup.cfg``), and the directory is removed afterwards. Everything else (the
metadata, editable installs, the requirements) is setuptools' own.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from setuptools import build_meta as _setuptools

__all__ = [
    "build_editable",
    "build_sdist",
    "build_wheel",
    "get_requires_for_build_editable",
    "get_requires_for_build_sdist",
    "get_requires_for_build_wheel",
    "prepare_metadata_for_build_editable",
    "prepare_metadata_for_build_wheel",
]

_EXTRA = "DIST_EXTRA_CONFIG"


@contextlib.contextmanager
def _scratch_outside_the_tree() -> Iterator[None]:
    """Point setuptools' build and egg-info directories into a temporary directory."""
    previous = os.environ.get(_EXTRA)
    with tempfile.TemporaryDirectory(prefix="roger-build-") as scratch:
        base = Path(scratch)
        (base / "egg").mkdir()
        config = base / "setup.cfg"
        # a configuration the caller gave through the same variable still applies; these two
        # options are read after it and so win
        own = Path(previous).read_text(encoding="utf-8") if previous else ""
        config.write_text(own + f"\n[build]\nbuild_base = {base / 'build'}\n"
                          f"\n[egg_info]\negg_base = {base / 'egg'}\n", encoding="utf-8")
        os.environ[_EXTRA] = str(config)
        try:
            yield
        finally:
            if previous is None:
                os.environ.pop(_EXTRA, None)
            else:
                os.environ[_EXTRA] = previous


def get_requires_for_build_wheel(config_settings: dict[str, Any] | None = None) -> list[str]:
    """What building a wheel needs besides ``build-system.requires`` (setuptools' answer)."""
    with _scratch_outside_the_tree():
        return list(_setuptools.get_requires_for_build_wheel(config_settings))


def get_requires_for_build_sdist(config_settings: dict[str, Any] | None = None) -> list[str]:
    """What building an sdist needs besides ``build-system.requires`` (setuptools' answer)."""
    with _scratch_outside_the_tree():
        return list(_setuptools.get_requires_for_build_sdist(config_settings))


def get_requires_for_build_editable(config_settings: dict[str, Any] | None = None) -> list[str]:
    """What an editable install needs besides ``build-system.requires`` (setuptools' answer)."""
    with _scratch_outside_the_tree():
        return list(_setuptools.get_requires_for_build_editable(config_settings))


def prepare_metadata_for_build_wheel(metadata_directory: str,
                                     config_settings: dict[str, Any] | None = None) -> str:
    """Write the wheel's ``.dist-info`` into ``metadata_directory``."""
    with _scratch_outside_the_tree():
        name: str = _setuptools.prepare_metadata_for_build_wheel(metadata_directory,
                                                                 config_settings)
    return name


def prepare_metadata_for_build_editable(metadata_directory: str,
                                        config_settings: dict[str, Any] | None = None) -> str:
    """Write the editable wheel's ``.dist-info`` into ``metadata_directory``."""
    with _scratch_outside_the_tree():
        name: str = _setuptools.prepare_metadata_for_build_editable(metadata_directory,
                                                                    config_settings)
    return name


def build_wheel(wheel_directory: str, config_settings: dict[str, Any] | None = None,
                metadata_directory: str | None = None) -> str:
    """Build the wheel into ``wheel_directory``, leaving the source tree as it was."""
    with _scratch_outside_the_tree():
        name: str = _setuptools.build_wheel(wheel_directory, config_settings, metadata_directory)
    return name


def build_sdist(sdist_directory: str, config_settings: dict[str, Any] | None = None) -> str:
    """Build the sdist into ``sdist_directory``, leaving the source tree as it was."""
    with _scratch_outside_the_tree():
        name: str = _setuptools.build_sdist(sdist_directory, config_settings)
    return name


def build_editable(wheel_directory: str, config_settings: dict[str, Any] | None = None,
                   metadata_directory: str | None = None) -> str:
    """Build the editable wheel (``pip install -e .``) into ``wheel_directory``."""
    with _scratch_outside_the_tree():
        name: str = _setuptools.build_editable(wheel_directory, config_settings,
                                               metadata_directory)
    return name
