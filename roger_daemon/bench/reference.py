"""The learner of another git revision, importable beside this one (``roger bench learner
--compare REF``).

``roger_daemon/learner`` is self-contained (it imports nothing else from ``roger_daemon``), so
the files of revision ``REF`` are written by ``git show`` into a directory of the system's
temporary directory, ``roger-ref-<sha>``, as a package ``_roger_ref_<sha>`` (every
``roger_daemon.learner`` in them renamed to it) and imported from there: the old and the new
implementation then run in one process, on the same machine at the same moment.  Needs the git
repository this package was installed from (an editable install or a checkout).
"""

from __future__ import annotations

import importlib
import subprocess
import sys
import tempfile
from pathlib import Path
from types import ModuleType

from roger_daemon.atomic import write_text

__all__ = ["RevisionError", "load_reference"]

_ROOT = Path(__file__).resolve().parents[2]
_LEARNER = "roger_daemon/learner"


class RevisionError(RuntimeError):
    """The revision cannot be found or its learner cannot be imported."""


def _git(*args: str) -> str:
    try:
        out = subprocess.run(["git", "-C", str(_ROOT), *args], check=True, capture_output=True,
                             text=True)
    except (OSError, subprocess.CalledProcessError) as exc:
        detail = getattr(exc, "stderr", "") or str(exc)
        raise RevisionError(f"git {' '.join(args)}: {detail.strip()}") from None
    return out.stdout


def load_reference(rev: str) -> tuple[ModuleType, str]:
    """``(package, full sha)``: revision ``rev``'s ``roger_daemon.learner``, imported afresh."""
    sha = _git("rev-parse", "--verify", f"{rev}^{{commit}}").strip()
    files = [f for f in _git("ls-tree", "-r", "--name-only", sha, _LEARNER).splitlines()
             if f.endswith(".py")]
    if not files:
        raise RevisionError(f"{rev} ({sha[:12]}) has no {_LEARNER}")
    name = f"_roger_ref_{sha[:12]}"
    if name in sys.modules:
        return sys.modules[name], sha
    # one directory per revision, written once: its files keep their times, so numba's on-disk
    # cache of a revision's compiled kernels stays valid from one run to the next
    root = Path(tempfile.gettempdir()) / f"roger-ref-{sha[:12]}"
    for f in files:
        dest = root / name / Path(f).relative_to(_LEARNER)
        if dest.exists():
            continue
        text = _git("show", f"{sha}:{f}").replace("roger_daemon.learner", name)
        dest.parent.mkdir(parents=True, exist_ok=True)
        write_text(dest, text)  # atomic: never a half-written module, even with two runs at once
    if str(root) not in sys.path:
        sys.path.append(str(root))  # kept: the package may import its modules lazily
    try:
        return importlib.import_module(name), sha
    except Exception as exc:  # an old revision that does not import here
        raise RevisionError(f"{rev} ({sha[:12]}): importing its learner failed: {exc}") from exc
