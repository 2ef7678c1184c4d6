"""The packages depend one way: protocols <- roger_daemon <- simulator, and never back.

* importing every module of ``roger_daemon`` (and of ``protocols``) in a fresh interpreter loads
  no module of the packages above it;
* no module of a lower package names a higher one in a string that could be imported
  (``importlib.import_module("simulator...")``, a command table row): the simulator's
  subcommands reach ``roger`` through the ``roger.commands`` entry point instead.
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
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
