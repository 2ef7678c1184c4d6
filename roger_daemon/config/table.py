"""Typed, key-naming readers of one TOML table (every rejection names its key)."""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from protocols.keys import validate_robot_id
from roger_daemon.config.settings import ConfigError

__all__ = ["Table", "bad", "show"]

_ID_FORM = "a string of 1-64 characters [A-Za-z0-9_-]"
_MISSING = object()


def show(value: Any) -> str:
    """A value as the user wrote it in TOML (strings quoted)."""
    try:
        return json.dumps(value)
    except (TypeError, ValueError):
        return repr(value)


def bad(key: str, expected: str, value: Any) -> ConfigError:
    """The error for ``key``: what was expected and what was given."""
    return ConfigError(key, f"{key} must be {expected}, got {show(value)}")


class Table:
    """A TOML table being consumed: every key read is ticked off; leftovers are unknown keys."""

    def __init__(self, data: Any, prefix: str) -> None:
        if not isinstance(data, dict):
            raise bad(prefix or "(top level)", "a table", data)
        self.data: dict[str, Any] = data
        self.prefix = prefix
        self.seen: set[str] = set()

    def key(self, name: str) -> str:
        """The dotted TOML key of ``name`` in this table."""
        return f"{self.prefix}.{name}" if self.prefix else name

    def raw(self, name: str, default: Any = _MISSING) -> Any:
        """The raw value of ``name``, ticked off as known (``default`` if absent, else required)."""
        self.seen.add(name)
        if name in self.data:
            return self.data[name]
        if default is _MISSING:
            raise ConfigError(self.key(name), f"{self.key(name)} is required")
        return default

    def number(self, name: str, default: float, *, lo: float = 0.0, lo_open: bool = True) -> float:
        """A finite number above ``lo`` (or at least ``lo`` when not ``lo_open``)."""
        v = self.raw(name, default)
        op = ">" if lo_open else ">="
        want = f"a number {op} {lo:g}"
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise bad(self.key(name), want, v)
        if (v <= lo) if lo_open else (v < lo):
            raise bad(self.key(name), want, v)
        return float(v)

    def integer(self, name: str, default: int, *, lo: int = 0) -> int:
        """An integer >= ``lo`` (booleans are not integers here)."""
        v = self.raw(name, default)
        if isinstance(v, bool) or not isinstance(v, int) or v < lo:
            raise bad(self.key(name), f"an integer >= {lo}", v)
        return v

    def boolean(self, name: str, default: bool) -> bool:
        """``true`` or ``false``."""
        v = self.raw(name, default)
        if not isinstance(v, bool):
            raise bad(self.key(name), "true or false", v)
        return v

    def choice(self, name: str, default: str, choices: Sequence[str]) -> str:
        """One of ``choices``."""
        v = self.raw(name, default)
        if v not in choices:
            raise bad(self.key(name), "one of " + ", ".join(show(c) for c in choices), v)
        return str(v)

    def string(self, name: str, default: Any = _MISSING) -> str:
        """A non-empty string."""
        v = self.raw(name, default)
        if not isinstance(v, str) or not v:
            raise bad(self.key(name), "a non-empty string", v)
        return v

    def ident(self, name: str, default: Any = _MISSING) -> str:
        """An identifier (the robot-id form: 1-64 characters ``[A-Za-z0-9_-]``)."""
        v = self.raw(name, default)
        try:
            return validate_robot_id(v)
        except Exception:
            raise bad(self.key(name), _ID_FORM, v) from None

    def path(self, name: str, default: Path | None) -> Path | None:
        """A path (``None`` for an empty string or when absent with no default)."""
        v = self.raw(name, default)
        if v is None or isinstance(v, Path):
            return v
        if not isinstance(v, str):
            raise bad(self.key(name), "a path (string)", v)
        return Path(v) if v else None

    def directory(self, name: str, default: Path) -> Path:
        """A directory's path: a non-empty string (an empty one is refused, never taken for
        the default)."""
        v = self.raw(name, default)
        if isinstance(v, Path):
            return v
        if not isinstance(v, str) or not v.strip():
            raise bad(self.key(name), "a directory (a non-empty path)", v)
        return Path(v)

    def strings(self, name: str, default: tuple[str, ...] | None) -> tuple[str, ...] | None:
        """An array of non-empty strings, as a tuple."""
        v = self.raw(name, default)
        if v is None or isinstance(v, tuple):
            return v
        if not isinstance(v, list) or not all(isinstance(e, str) and e for e in v):
            raise bad(self.key(name), "an array of strings", v)
        return tuple(v)

    def floats(self, name: str, length: int) -> tuple[float, ...] | None:
        """An optional array of exactly ``length`` finite numbers."""
        v = self.raw(name, None)
        if v is None:
            return None
        want = f"an array of {length} finite numbers"
        if (
            not isinstance(v, list)
            or len(v) != length
            or not all(
                isinstance(e, int | float) and not isinstance(e, bool) and math.isfinite(e)
                for e in v
            )
        ):
            raise bad(self.key(name), want, v)
        return tuple(float(e) for e in v)

    def sub(self, name: str) -> Table:
        """The sub-table ``name`` (empty when absent)."""
        return Table(self.raw(name, {}), self.key(name))

    def done(self) -> None:
        """Reject the first key of this table that was never read (an unknown key)."""
        unknown = sorted(set(self.data) - self.seen)
        if unknown:
            k = self.key(unknown[0])
            known = ", ".join(sorted(self.seen))
            raise ConfigError(k, f"unknown key {k} (known keys here: {known})")
