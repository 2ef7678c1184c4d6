"""The README is a user guide: short, current, its links resolve, its example runs as pasted and
every ``roger`` command it (or a reference page in docs/) shows exists with those options."""

from __future__ import annotations

import argparse
import ast
import json
import re
import shlex
import subprocess
import sys
from functools import cache
from pathlib import Path

import pytest

from roger_daemon.cli import BENCHES, COMMANDS, build_parser

ROOT = Path(__file__).parents[1]
README = ROOT / "README.md"
MAX_LINES = 350
#: The pages whose ``roger`` commands are checked besides the README's: every docs page but
#: the history, which quotes each command as it was run.
PAGES = sorted(p.relative_to(ROOT).as_posix() for p in (ROOT / "docs").glob("*.md")
               if p.name != "benchmark-history.md")


def _text(path: Path = README) -> str:
    return path.read_text(encoding="utf-8")


def test_readme_links_stay_inside_the_repository() -> None:
    text = _text()
    targets = re.findall(r"\]\(([^)\s]+)\)", text)
    assert targets, "the README has no links at all (figures are links too)"
    for target in targets:
        assert "://" not in target, f"link outside the repository: {target}"
        path = (ROOT / target.split("#")[0]).resolve()
        assert path.is_relative_to(ROOT.resolve()), f"link outside the repository: {target}"
        assert path.exists(), f"link to a missing file: {target}"
    assert "../shared" not in text


def test_readme_is_a_guide_not_a_notebook() -> None:
    """At most 350 lines, no dated run paragraphs, no commit hashes (those live in
    docs/benchmark-history.md and the CHANGELOG)."""
    text = _text()
    assert len(text.splitlines()) <= MAX_LINES
    assert "Re-run on" not in text
    hashes = [w for w in re.findall(r"\b[0-9a-f]{7,40}\b", text)
              if re.search(r"[a-f]", w) and re.search(r"[0-9]", w)]
    assert hashes == [], f"commit hashes in the README: {hashes}"
    assert not re.search(r"\b20\d\d-\d\d-\d\d\b", text), "a dated paragraph in the README"


def _python_blocks(text: str) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", text, re.MULTILINE | re.DOTALL)


def test_the_readme_has_a_python_example() -> None:
    assert _python_blocks(_text()), "the README's example is a ```python block"


@pytest.mark.parametrize("index", range(len(_python_blocks(_text()))))
def test_the_readme_python_example_runs_as_pasted(index: int, tmp_path: Path) -> None:
    code = _python_blocks(_text())[index]
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=240, cwd=tmp_path)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "Traceback" not in out.stderr


def _commands(text: str) -> list[str]:
    """Every ``roger ...`` command line of the text's code blocks and inline code spans."""
    found = []
    for block in re.findall(r"^```(?:sh|bash|console)?\n(.*?)^```", text, re.M | re.S):
        joined = block.replace("\\\n", " ")
        found += [line.strip() for line in joined.splitlines()]
    found += re.findall(r"`(roger [^`]+)`", text)
    indented = re.findall(r"^    (roger .+)$", text, re.MULTILINE)  # indented code
    return [c for c in found + indented if c.startswith("roger ")]


@cache
def _parser(table_name: str, name: str) -> argparse.ArgumentParser:
    table, prog = (BENCHES, "roger bench") if table_name == "bench" else (COMMANDS, "roger")
    return build_parser(table, prog, name)


def _subparser(parser: argparse.ArgumentParser, name: str) -> argparse.ArgumentParser | None:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction) and name in action.choices:
            sub: argparse.ArgumentParser = action.choices[name]
            return sub
    return None


def _words(command: str) -> list[str]:
    """The words after ``roger``: ``[...]`` marks optional parts, ``a|b`` alternatives (the
    first is checked)."""
    line = command.split(" #")[0].replace("[", " ").replace("]", " ")
    try:
        words = shlex.split(line)
    except ValueError:
        words = line.split()
    return [w if w.startswith("-") else w.split("|")[0] for w in words[1:]]


def _problems(command: str) -> list[str]:
    """What in ``command`` is not a subcommand or an option of ``roger``."""
    words = _words(command)
    if not words or words[0].startswith("-") or not words[0].islower() or "..." in words[0]:
        return []  # a placeholder (roger CMD, roger SUBCOMMAND, roger ...)
    table = "bench" if words[0] == "bench" and len(words) > 1 and words[1] in BENCHES else "roger"
    if table == "bench":
        words = words[1:]
    parser = _subparser(_parser(table, words[0]), words[0])
    if parser is None:
        return [f"{command}: no subcommand {words[0]!r}"]
    rest = words[1:]
    while rest and (sub := _subparser(parser, rest[0])) is not None:
        parser, rest = sub, rest[1:]
    if any(isinstance(a, argparse._SubParsersAction) for a in parser._actions) and not (
            rest and rest[0].startswith("-")):
        return [f"{command}: no subcommand {rest[0] if rest else ''!r} of {parser.prog}"]
    options = {o for a in parser._actions for o in a.option_strings}
    return [f"{command}: no option {w.split('=')[0]}" for w in rest
            if w.startswith("--") and w.split("=")[0] not in options]


@pytest.mark.parametrize("page", ["README.md", *PAGES])
def test_every_roger_command_shown_exists(page: str) -> None:
    commands = _commands(_text(ROOT / page))
    assert commands or page != "README.md"
    problems = [p for c in commands for p in _problems(c)]
    assert problems == [], "\n".join(problems)


def test_the_command_check_sees_a_missing_option() -> None:
    assert _problems("roger status --watch --json") == []
    assert _problems("roger bench learner --stream aibo --json") == []
    assert _problems("roger log export FILE --out DIR --format lerobot") == []
    assert _problems("roger status --nothing") == ["roger status --nothing: no option --nothing"]
    assert _problems("roger nothing") == ["roger nothing: no subcommand 'nothing'"]
    assert _problems("roger log nothing --json") != []
    assert _problems("roger log nothing") != []


def test_the_concept_figure_is_drawn_by_its_script(tmp_path: Path) -> None:
    out = tmp_path / "multimap.png"
    run = subprocess.run([sys.executable, str(ROOT / "docs/examples/multimap_figure.py"),
                          "--out", str(out)], capture_output=True, text=True, timeout=240,
                         cwd=ROOT)
    assert run.returncode == 0, run.stdout + run.stderr
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


#: Imports that go up a row of the README's map, on purpose (the map names each).
UPWARD = {("roger_daemon.recording", "roger_daemon.daemon.pairing")}


def _expand(path: str) -> list[str]:
    """``roger_daemon/{a,b}.py`` -> the dotted modules ``roger_daemon.a``, ``roger_daemon.b``."""
    m = re.fullmatch(r"(.*)\{([^}]*)\}(.*)", path)
    paths = [m.group(1) + part + m.group(3) for part in m.group(2).split(",")] if m else [path]
    return [p.removesuffix("/").removesuffix(".py").replace("/", ".") for p in paths]


def _map_rows() -> list[list[str]]:
    """The README's architecture table: per row, the packages and modules it names."""
    text = _text().split("## Architecture", 1)[1].split("\n## ", 1)[0]
    rows = []
    for line in text.splitlines():
        cells = line.split("|")
        if len(cells) > 3 and "`" in cells[2]:
            rows.append([m for p in re.findall(r"`([^`]+)`", cells[2]) for m in _expand(p)])
    return rows


def _row_of(module: str, rows: list[list[str]]) -> int | None:
    """The row of the longest name in the map that ``module`` is or lies under."""
    best: tuple[int, int] | None = None
    for i, names in enumerate(rows):
        for name in names:
            if (module == name or module.startswith(name + ".")) and (
                    best is None or len(name) > best[1]):
                best = (i, len(name))
    return None if best is None else best[0]


def _imports(path: Path) -> set[str]:
    """Every absolute import of ``path``, inside functions too."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
    return names


def test_the_architecture_map_is_the_import_structure() -> None:
    """Every module of the three packages is in a row of the map, and imports only from its
    own row and the rows above it (but for :data:`UPWARD`)."""
    rows = _map_rows()
    assert len(rows) >= 6, rows
    unplaced, upward = [], []
    for package in ("protocols", "roger_daemon", "simulator"):
        for path in sorted((ROOT / package).rglob("*.py")):
            module = ".".join(path.relative_to(ROOT).with_suffix("").parts)
            module = module.removesuffix(".__init__").removesuffix(".__main__")
            if module == "roger_daemon":
                continue  # the package's face: its version
            mine = _row_of(module, rows)
            if mine is None:
                unplaced.append(module)
                continue
            for target in _imports(path):
                theirs = _row_of(target, rows)
                if theirs is not None and theirs > mine and not any(
                        module.startswith(a) and target == b for a, b in UPWARD):
                    upward.append(f"{module} -> {target}")
    assert unplaced == [], f"modules the README's map does not place: {unplaced}"
    assert upward == [], "imports that go up the README's map:\n" + "\n".join(sorted(upward))


def test_the_results_tables_are_the_commands_output() -> None:
    """The README's results (between its ``results`` markers) are ``roger experiment table``'s
    output for the files the block names, not typed by hand."""
    from simulator.experiment.table import markdown, peers_table

    text = README.read_text(encoding="utf-8")
    block = text[text.index("<!-- results:begin -->"):text.index("<!-- results:end -->")]
    tables = "\n".join(line for line in block.splitlines() if line.startswith("|"))
    figures = ROOT / "docs" / "figures"
    results = json.loads((figures / "streams" / "results.json").read_text())
    peers = [json.loads((figures / "peers" / f"results-{p}.json").read_text())
             for p in ("act", "diffusion")]
    assert "docs/figures/streams/results.json" in block
    expected = markdown(results) + "\n" + peers_table(peers)
    assert tables == expected
