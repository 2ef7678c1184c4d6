"""The packages depend one way: protocols <- roger_daemon <- simulator, and never back; and
inside the learner, the paper's classes sit on its engine, never the other way round.

* importing every module of ``roger_daemon`` (and of ``protocols``) in a fresh interpreter loads
  no module of the packages above it;
* no module of a lower package names a higher one in a string that could be imported
  (``importlib.import_module("simulator...")``, a command table row): the simulator's
  subcommands reach ``roger`` through the ``roger.commands`` entry point instead;
* ``roger_daemon/learner`` imports nothing else of ``roger_daemon`` (``roger bench learner
  --compare`` imports an old revision's learner on its own); no module of its engine
  (``learner/engine/``: kernels, buffers, packed storage, the expert store) imports one of the
  paper's modules above it; and no two learner modules import each other, directly or round a
  circle.  Every import statement counts, inside functions and ``TYPE_CHECKING`` blocks too.
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ABOVE = {"protocols": ("roger_daemon", "simulator"), "roger_daemon": ("simulator",)}

_PROBE = """
import importlib, json, pkgutil, sys
pkg = importlib.import_module(sys.argv[1])
names = [m.name for m in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + ".")
         if not m.name.endswith("__main__")]
for name in names:
    importlib.import_module(name)
print(json.dumps({"imported": names, "loaded": sorted(sys.modules)}))
"""


@pytest.mark.parametrize("package", sorted(ABOVE))
def test_importing_a_package_loads_nothing_above_it(package: str) -> None:
    out = subprocess.run([sys.executable, "-c", _PROBE, package], capture_output=True,
                         text=True, check=True, cwd=ROOT, timeout=240)
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert len(got["imported"]) > 3
    above = [m for m in got["loaded"] if m.split(".")[0] in ABOVE[package]]
    assert above == [], f"importing {package} loads {above}"


def _module_strings(path: Path) -> list[tuple[int, str]]:
    """String constants of ``path`` that are not docstrings."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    docstrings = {id(node.body[0].value) for node in ast.walk(tree)
                  if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef)
                  and node.body and isinstance(node.body[0], ast.Expr)
                  and isinstance(node.body[0].value, ast.Constant)}
    return [(n.lineno, n.value) for n in ast.walk(tree)
            if isinstance(n, ast.Constant) and isinstance(n.value, str)
            and id(n) not in docstrings]


@pytest.mark.parametrize("package", sorted(ABOVE))
def test_no_module_names_a_package_above_it_by_string(package: str) -> None:
    found = []
    for path in sorted((ROOT / package).rglob("*.py")):
        for line, text in _module_strings(path):
            top = text.strip().split(".")[0]
            if top in ABOVE[package] and all(p.isidentifier() for p in text.strip().split(".")):
                found.append(f"{path.relative_to(ROOT)}:{line}: {text!r}")
    assert found == []


def test_the_simulator_commands_reach_roger_through_the_entry_point() -> None:
    from roger_daemon.cli import BENCHES, COMMANDS
    from simulator import commands

    assert set(commands.COMMANDS) <= set(COMMANDS) and set(commands.BENCHES) <= set(BENCHES)
    for name, row in commands.COMMANDS.items():
        assert COMMANDS[name] == row


LEARNER = "roger_daemon.learner"
ENGINE = f"{LEARNER}.engine"


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
    return ".".join(parts)


def _imports(path: Path, modules: frozenset[str]) -> set[str]:
    """The modules of ``modules`` that ``path`` imports: ``import a.b``, ``from a import b``
    (``a.b`` if that is a module, else ``a``), relative imports resolved; anywhere in the file."""
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join([*up, base] if base else up)
            found.update(f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base
                         for a in node.names)
    return {m for m in found if m in modules} - {name}


@cache
def _learner_graph() -> dict[str, set[str]]:
    paths = sorted((ROOT / "roger_daemon" / "learner").rglob("*.py"))
    modules = frozenset(_module_name(p) for p in paths)
    return {_module_name(p): _imports(p, modules) for p in paths}


def _circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            part = []
            while True:
                w = stack.pop()
                part.append(w)
                if w == v:
                    break
            if len(part) > 1:
                out.append(sorted(part))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_the_circle_finder_finds_a_circle() -> None:
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": set()}
    assert _circles(graph) == [["a", "b", "c"]]
    assert _circles({"a": {"b"}, "b": set()}) == []


def test_the_learner_graph_sees_every_kind_of_import() -> None:
    graph = _learner_graph()
    assert f"{ENGINE}.store" in graph and f"{LEARNER}.roger" in graph
    assert f"{ENGINE}.store" in graph[f"{LEARNER}.roger"]  # from ... import ExpertStore
    assert f"{ENGINE}.jit_batch" in graph[f"{ENGINE}.jit"]  # inside a function
    assert f"{ENGINE}.jit" in graph[f"{LEARNER}.history"]  # from package import module


def test_the_learner_imports_nothing_else_of_roger_daemon() -> None:
    found = []
    for path in sorted((ROOT / "roger_daemon" / "learner").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            found += [f"{path.relative_to(ROOT)}: {n}" for n in names
                      if n.split(".")[0] == "roger_daemon" and not n.startswith(LEARNER)]
    assert found == []


def test_the_engine_imports_none_of_the_papers_modules() -> None:
    graph = _learner_graph()
    engine = [m for m in graph if m == ENGINE or m.startswith(ENGINE + ".")]
    assert len(engine) > 10
    above = {m: sorted(w for w in graph[m] if not w.startswith(ENGINE)) for m in engine}
    assert {m: w for m, w in above.items() if w} == {}


def test_no_learner_modules_import_each_other_round_a_circle() -> None:
    assert _circles(_learner_graph()) == []

