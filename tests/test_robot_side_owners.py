"""One owner per rule of the robot's side of the protocol (issue 56, docs/your-robot.md).

* the wire format: every message is built and encoded by :mod:`protocols` (``encode``,
  ``decode``, :mod:`protocols.keys`); no module of the simulator, nor the robot-side client,
  imports msgpack or spells a ``roger/<robot>/<kind>`` key itself;
* publishing: a Zenoh publisher is declared in one place per rule: the robot's own messages
  to the daemon (``roger_daemon.client.robot_publisher``: BLOCK, REAL_TIME, express), the
  simulator's streams (``simulator.transport.publisher``: DROP, express), the daemon's
  outputs (``roger_daemon.transport``) and the replay of a recording's topics
  (``roger_daemon.recording.publish``). ``roger teach`` (the simulator in one process) and
  the fleet benchmark's client go through them too.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PUBLISHERS = {"roger_daemon/client.py", "simulator/transport.py", "roger_daemon/transport.py",
              "roger_daemon/recording/publish.py"}
ROBOT_SIDE = ["roger_daemon/client.py", "roger_daemon/harness.py",
              *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "simulator").rglob("*.py"))]
KEY = re.compile(r"""["']roger/(\{|[a-z0-9_-]+/(perception|action|command|prediction|episode|"""
                 r"""status|control)["'])""")


def _sources() -> list[Path]:
    return sorted(p for top in ("roger_daemon", "simulator", "protocols", "scripts")
                  for p in (ROOT / top).rglob("*.py"))


def _declares_publisher(tree: ast.AST) -> list[int]:
    return [n.lineno for n in ast.walk(tree) if isinstance(n, ast.Call)
            and isinstance(n.func, ast.Attribute) and n.func.attr == "declare_publisher"]


def test_zenoh_publishers_are_declared_by_the_owners_of_their_rules_only() -> None:
    found = {str(p.relative_to(ROOT)): lines for p in _sources()
             if (lines := _declares_publisher(ast.parse(p.read_text(encoding="utf-8"))))}
    assert set(found) == PUBLISHERS, {k: v for k, v in found.items() if k not in PUBLISHERS}


@pytest.mark.parametrize("path", ROBOT_SIDE)
def test_the_robot_side_encodes_only_through_protocols(path: str) -> None:
    text = (ROOT / path).read_text(encoding="utf-8")
    imported = {a.name.split(".")[0] for n in ast.walk(ast.parse(text))
                if isinstance(n, ast.Import | ast.ImportFrom)
                for a in (n.names if isinstance(n, ast.Import) else [ast.alias(n.module or "")])}
    assert "msgpack" not in imported
    assert not KEY.search(text), KEY.search(text)
