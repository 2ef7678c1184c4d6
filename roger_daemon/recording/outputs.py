"""Where a log command writes: ``--out`` is always a directory (one rule for every command).

``roger record``, ``demo``, ``experiment`` and the dataset exports write several files, so
``--out`` names a directory everywhere; a command that writes one file puts it there under
the input's name (``roger log recover LOG --out DIR`` writes ``DIR/<LOG's name>``). Without
``--out`` the file goes beside the input. The earlier spelling, ``--out FILE.mcap`` (a path
ending in ``.mcap`` that is not a directory), still works and says it is deprecated.
``--out -`` (standard output) is refused: the outputs are binary files with an index.
"""

from __future__ import annotations

import sys
from pathlib import Path

from roger_daemon.console import UsageError

__all__ = ["bad_input", "existing_output", "output_file", "refuse_stdout"]


def refuse_stdout(command: str, out: Path | None) -> None:
    """``UsageError`` for ``--out -``."""
    if out is not None and str(out) == "-":
        raise UsageError(f"roger {command}: --out must be a directory, got '-' (standard output "
                         "is not supported: the output is a binary file with an index)")


def output_file(command: str, out: Path | None, default: Path, suffix: str = ".mcap") -> Path:
    """The file a one-file command writes: ``default`` (beside the input) without ``--out``,
    ``out / default.name`` for a directory, ``out`` itself for the deprecated file form."""
    refuse_stdout(command, out)
    if out is None:
        return default
    if out.suffix == suffix and not out.is_dir():
        print(f"roger {command}: warning: --out FILE is deprecated; --out takes a directory "
              f"(this writes {out})", file=sys.stderr)
        return out
    if out.exists() and not out.is_dir():
        raise UsageError(f"roger {command}: --out must be a directory, got the file {out}")
    return out / default.name  # the caller creates the directory when it writes


def bad_input(command: str, path: Path) -> bool:
    """Print why ``path`` is not a readable log (the shared check) and return True if so."""
    from roger_daemon.recording.mcapio import not_an_mcap_file

    why = not_an_mcap_file(path)
    if why:
        print(f"roger log {command}: {why}", file=sys.stderr)
    return bool(why)


def existing_output(command: str, out: Path, force: bool) -> bool:
    """True (with a message) if ``out`` exists and may not be overwritten."""
    if out.is_dir():
        print(f"roger log {command}: output {out} is a directory; expected a file name",
              file=sys.stderr)
        return True
    if out.exists() and not force:
        print(f"roger log {command}: output {out} exists; pass --force to overwrite it",
              file=sys.stderr)
        return True
    return False
