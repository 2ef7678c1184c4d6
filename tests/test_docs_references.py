"""Every document the code, tests, configs and docs cite is in the repository.

* No citation of a reference document that lives outside the repository (the shared folder's
  AIBO facts, Zenoh/MCAP/systemd notes and ROGER math reference, or any ``../shared`` path).
* Every ``<file>.md §N`` citation names an existing file and a section heading ``§N`` in it;
  a bare ``§N`` in a file that cites exactly one such document must exist in that document
  (in a ``docs/*.md`` file, in the file itself).
* Every "pitfall N" is a numbered note of ``docs/learner-math.md`` §7, in a file that names
  that document.
* Every code path a ``docs/*.md`` page names (``roger_daemon/.../x.py``, ``scripts/...``,
  ``tests/...``; not ``configs/``, where the docs' examples name the user's own files) is a file
  or folder of the repository: a moved module takes its references along.
"""

from __future__ import annotations

import re
import subprocess
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SUFFIXES = {".py", ".md", ".toml", ".json5"}
SKIP_DIRS = {".venv", ".git", "build", "dist", "__pycache__", "node_modules"}

# Names of the outside documents, split so that this file does not match itself.
_OUTSIDE = "|".join(
    [
        "roger" + "-math",
        "aibo-soccer" + "-facts",
        "zenoh-mcap" + "-systemd",
        r"\bfacts\s+(?:sections?\s+)?\d",
        r"\.\./" + "shared",
        "shared" + "/reference",
    ]
)
OUTSIDE = re.compile(_OUTSIDE, re.IGNORECASE)
# Lines that name an outside path on purpose (checking its absence).
ALLOWED = {("tests/test_readme.py", '"../shared" not in text')}

_SEC = r"§\d+(?:\.\d+)*"
CITATION = re.compile(
    rf"([\w./-]+\.md)`{{0,2}}\)?\s+({_SEC}(?:(?:\s*,\s*|\s+and\s+|\s*-\s*|\s*–\s*){_SEC})*)"
)
SECTION = re.compile(_SEC)
HEADING = re.compile(rf"^#+\s+({_SEC})\b", re.MULTILINE)
PITFALL = re.compile(r"\bpitfalls?\s+(\d+)(?:\s*-\s*(\d+))?")
LEARNER_MATH = "docs/learner-math.md"


def _candidates() -> list[Path]:
    """The repository's files: what git tracks or would track (not what it ignores, such as
    ``runs/`` written by ``make demo``); every file below the root outside a git checkout."""
    try:
        listed = subprocess.run(
            ["git", "ls-files", "--cached", "--others", "--exclude-standard", "-z"],
            cwd=ROOT, capture_output=True, check=True, timeout=60).stdout
    except (OSError, subprocess.SubprocessError):
        return sorted(ROOT.rglob("*"))
    return sorted(ROOT / name for name in listed.decode().split("\0") if name)


def _files() -> list[Path]:
    out = []
    for path in _candidates():
        rel = path.relative_to(ROOT)
        if any(part in SKIP_DIRS or part.startswith(".") for part in rel.parts[:-1]):
            continue
        if path.suffix in SUFFIXES and path.is_file() and path != Path(__file__).resolve():
            out.append(path)
    return out


FILES = _files()


def _rel(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


@cache
def _sections(doc: str) -> frozenset[str]:
    return frozenset(HEADING.findall((ROOT / doc).read_text(encoding="utf-8")))


def _resolve(name: str) -> str | None:
    """The repository path a cited ``*.md`` name refers to (``docs/`` may be left out)."""
    for cand in (name, f"docs/{Path(name).name}"):
        if (ROOT / cand).is_file():
            return cand
    return None


def _citations(text: str) -> list[tuple[str, list[str]]]:
    return [(m.group(1), SECTION.findall(m.group(2))) for m in CITATION.finditer(text)]


def _pitfall_numbers() -> set[int]:
    text = (ROOT / LEARNER_MATH).read_text(encoding="utf-8")
    start = text.index("## §7")
    end = text.index("\n## ", start + 1)
    nums: set[int] = set()
    for a, b in re.findall(r"^\* (\d+)(?:-(\d+))?:", text[start:end], re.MULTILINE):
        nums.update(range(int(a), int(b or a) + 1))
    return nums


def test_the_scan_sees_the_tree() -> None:
    names = {_rel(p) for p in FILES}
    assert {"simulator/config.py", "docs/aibo-simulation.md", "docs/zenoh-notes.md"} <= names
    assert not any(n.startswith(".venv/") for n in names)


@pytest.mark.parametrize("path", FILES, ids=_rel)
def test_no_citation_of_a_document_outside_the_repository(path: Path) -> None:
    rel = _rel(path)
    bad = [
        f"{rel}:{i}: {line.strip()}"
        for i, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
        if OUTSIDE.search(line) and not any(rel == f and s in line for f, s in ALLOWED)
    ]
    assert not bad, "cite the in-repository document instead:\n" + "\n".join(bad)


@pytest.mark.parametrize("path", FILES, ids=_rel)
def test_cited_sections_exist(path: Path) -> None:
    rel = _rel(path)
    text = path.read_text(encoding="utf-8")
    problems = []
    cited: set[str] = set()
    for name, secs in _citations(text):
        doc = _resolve(name)
        if doc is None:
            problems.append(f"{name}: no such file in the repository")
            continue
        cited.add(doc)
        problems += [f"{doc} has no heading {s}" for s in secs if s not in _sections(doc)]
    # Bare "§N": in a docs page it refers to the page itself; in a file citing exactly one
    # document, to that document.
    home = rel if rel.startswith("docs/") and _sections(rel) else None
    if home is None and len(cited) == 1:
        home = next(iter(cited))
    if home is not None:
        stripped = CITATION.sub("", text)
        problems += [
            f"{home} has no heading {s} (bare {s} in {rel})"
            for s in sorted(set(SECTION.findall(stripped)))
            if s not in _sections(home)
        ]
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize("path", FILES, ids=_rel)
def test_pitfalls_are_learner_math_notes(path: Path) -> None:
    text = path.read_text(encoding="utf-8")
    found = PITFALL.findall(text)
    if not found:
        return
    assert _rel(path) == LEARNER_MATH or LEARNER_MATH in text or "learner-math.md" in text, (
        f"{_rel(path)} cites pitfalls without naming {LEARNER_MATH}"
    )
    known = _pitfall_numbers()
    missing = {
        n for a, b in found for n in range(int(a), int(b or a) + 1) if n not in known
    }
    assert not missing, f"{LEARNER_MATH} §7 has no pitfall {sorted(missing)}"


REPO_PATH = re.compile(r"\b((?:roger_daemon|simulator|protocols|scripts|tests)"
                       r"/[\w./*-]*[\w*])")  # a ``*`` is a glob; ``<name>`` ends the path
DOCS = [p for p in FILES if _rel(p).startswith("docs/") and p.suffix == ".md"]


def test_the_path_check_sees_a_missing_file() -> None:
    found = REPO_PATH.findall("see `roger_daemon/learner/engine/jit_nothing.py`, scripts/x.py, "
                              "tests/learner/test_jit*.py, tests/data/sessions/<s>.mcap.")
    assert found == ["roger_daemon/learner/engine/jit_nothing.py", "scripts/x.py",
                     "tests/learner/test_jit*.py", "tests/data/sessions"]
    assert [_exists(f) for f in found] == [False, False, True, True]


def _exists(name: str) -> bool:
    """A file or folder of the repository, or a glob that matches one."""
    return any(ROOT.glob(name)) if "*" in name else (ROOT / name).exists()


@pytest.mark.parametrize("path", DOCS, ids=_rel)
def test_repository_paths_in_docs_exist(path: Path) -> None:
    missing = sorted({f"{_rel(path)}: {name}" for name in
                      REPO_PATH.findall(path.read_text(encoding="utf-8")) if not _exists(name)})
    assert missing == [], "a document names a path that is not in the repository"

