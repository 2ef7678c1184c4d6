"""``roger play`` (simulator/controllers/play_node.py, roger_daemon/fsm/player.py): the robot
plays alone, with nothing of the hand-coded controller and no demonstrator label; and for real,
on loopback, the robot moves under it (``roger up`` with ``controller.role = "play"``)."""

from __future__ import annotations

import json
import subprocess
import sys
from functools import cache
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from cli_testing import in_process
from daemon_sessions import daemon_checkpoint
from test_import_graph import ROOT, _imports, _module_name

from protocols.messages import Dims
from roger_daemon.config import parse_config
from roger_daemon.fsm.online import RogerFSM
from roger_daemon.fsm.player import load_player

#: what the autonomous path must never reach: the hand-coded controller, its transitioner rule,
#: the experiment (which runs the HCC) and the daemon's label bookkeeping
FORBIDDEN = ("simulator.controllers.hcc", "simulator.controllers.transitioner",
             "simulator.controllers.hcc_node", "simulator.experiment", "roger_daemon.labels")
AUTONOMOUS = ("simulator.controllers.play_node", "roger_daemon.fsm.player")
pytestmark = pytest.mark.integration  # real processes, Zenoh on loopback (scouting off)

BENCH = ROOT / "roger_daemon" / "bench" / "data" / "aibo-demonstrations.npz"


def _reach(start: str) -> set[str]:
    """Every repository module ``start`` imports, transitively (every import statement)."""
    paths = {_module_name(p): p for pkg in ("protocols", "roger_daemon", "simulator")
             for p in (ROOT / pkg).rglob("*.py")}
    modules = frozenset(paths)
    seen, todo = set(), [start]
    while todo:
        m = todo.pop()
        if m in seen or m not in paths:
            continue
        seen.add(m)
        parts = m.split(".")
        todo.extend(".".join(parts[:k]) for k in range(1, len(parts)))  # parent packages
        todo.extend(_imports(paths[m], modules))
    return seen


@pytest.mark.parametrize("start", AUTONOMOUS)
def test_the_autonomous_path_imports_nothing_of_the_hcc(start: str) -> None:
    reached = _reach(start)
    assert "roger_daemon.fsm.controller" in reached  # the walk sees the imports
    bad = sorted(m for m in reached if m.startswith(FORBIDDEN))
    assert bad == [], f"{start} reaches {bad}"


def test_the_import_check_sees_the_hcc_where_it_is() -> None:
    assert "simulator.controllers.hcc" in _reach("simulator.controllers.hcc_node")


@cache
def _trained(points: int = 300) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """A roger+fsm model that learned the first ``points`` shipped AIBO demonstration pairs
    (the daemon's default parameters): its state dict, and the perceptions."""
    with np.load(BENCH) as data:
        x, y = data["x"][:points], data["y"][:points]
    model = RogerFSM(23, 9, parse_config({}).robots[0].params, seed=0)
    for i in range(points):
        model.learn_one(x[i], y[i])
    return model.state_dict(), x


def _checkpoint_dir(tmp_path: Path) -> Path:
    state, x = _trained()
    ckdir = tmp_path / "checkpoints"
    n = int(json.loads(str(state["fsm.meta"]))["n_observed"])
    daemon_checkpoint(ckdir, "aibo", state, dims=Dims(23, 9), labels=[""] * n)
    return ckdir


class _NoLabel:
    """A multimap row whose ``label`` must never be read."""

    def __init__(self, e: int, p: float, mean: np.ndarray, n: int) -> None:
        self.expert, self.p, self.mean, self.n = e, p, mean, n

    @property
    def label(self) -> str:
        raise AssertionError("the autonomous path read a demonstrator label")


_RUNTIME = """
import sys
for name in ("simulator.controllers.hcc", "simulator.controllers.transitioner",
             "roger_daemon.labels"):
    sys.modules[name] = None  # any import of them raises ImportError
import simulator.controllers.play_node as node
player = node.load_player(sys.argv[1])
print(sorted(m for m in sys.modules if m.startswith("simulator.experiment")))
"""


def test_the_player_reads_no_label_and_runs_without_the_hcc(tmp_path: Path) -> None:
    ckdir = _checkpoint_dir(tmp_path)
    out = subprocess.run([sys.executable, "-c", _RUNTIME, str(ckdir)], capture_output=True,
                         text=True, cwd=ROOT, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"
    from roger_daemon.learner import load_model

    state, x = _trained()
    model = load_model({k: v for k, v in state.items() if not k.startswith("fsm.")})
    a, b = load_player(ckdir), load_player(ckdir)
    moved = 0.0
    for t in range(120):
        _, table = model.predict_table(x[t])
        rows = [_NoLabel(e, p, table.means[j], n) for j, (e, p, n) in
                enumerate(zip(table.expert_ids, table.gate_probs, table.n_points, strict=True))]
        plain = [SimpleNamespace(expert=e, p=p, mean=table.means[j], n=n, label=f"junk{t}")
                 for j, (e, p, n) in enumerate(zip(table.expert_ids, table.gate_probs,
                                                   table.n_points, strict=True))]
        ya, how = a.command(x[t], rows, np.zeros(9))
        yb, _ = b.command(x[t], plain, np.zeros(9))
        np.testing.assert_array_equal(ya, yb)  # labels changed nothing
        assert how == "learned" and a.state in table.expert_ids
        moved += float(np.abs(ya[:3]).sum())
    assert moved > 0  # some expert walks


def test_play_refuses_a_checkpoint_without_transitions(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """In this process (tests/cli_testing.py: a traceback fails the test here)."""
    from roger_daemon.learner import Roger

    plain = Roger(23, 9, parse_config({}).robots[0].params, seed=0)
    daemon_checkpoint(tmp_path / "ck", "aibo", plain.state_dict(), dims=Dims(23, 9), labels=[])
    with in_process(capsys, monkeypatch) as run:
        out = run("play", "--checkpoint", str(tmp_path / "ck"))
    assert out.returncode == 2 and "holds no learned transitions" in out.stderr
    assert "--model roger+fsm" in out.stderr


def test_the_robot_moves_under_roger_play_on_loopback(tmp_path: Path) -> None:
    run = tmp_path / "run"
    _checkpoint_dir(run)
    launch = tmp_path / "up.toml"
    launch.write_text(f"""
[session]
dir = "{run}"
stop_timeout_s = 20.0
[ports]
daemon = 0
sim = 0
[sim]
locations = "0"
time_limit = 6.0
args = ["--vision", "fast", "--results", "results.json", "--command-timeout", "20"]
[controller]
role = "play"
args = ["--stats", "play.json", "--prediction-timeout", "20"]
""", encoding="utf-8")  # 20 s, not 2: a round trip past 2 s on loaded cores was a hold tick
    out = subprocess.run([sys.executable, "-m", "roger_daemon", "up", str(launch)],
                         capture_output=True, text=True, timeout=240)
    assert out.returncode == 0, out.stdout + out.stderr
    stats = json.loads((run / "play.json").read_text())
    assert stats["role"] == "play" and stats["learned"] > 100 and stats["no_prediction"] == 0
    assert len(stats["state_ticks"]) >= 1
    episode = json.loads((run / "results.json").read_text())["episodes"][0]
    # the robot moved on its own: it walked, or started a kick or trap motion (kicks in place
    # are the learned controller's commonest failure, docs/autonomy.md)
    assert episode["path_m"] > 0.01 or episode["kicks"] + episode["traps"] > 0, episode
    assert episode["ticks"] == 180 and episode["command_timeouts"] == 0
