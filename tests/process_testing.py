"""Process inspection shared by the tests that stop a command and check what it left."""

from __future__ import annotations

from pathlib import Path

__all__ = ["processes_naming"]


def processes_naming(text: str) -> list[str]:
    """Command lines of running processes that contain ``text`` (from /proc)."""
    found = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if text in cmd:
            found.append(cmd)
    return found
