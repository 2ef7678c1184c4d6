"""Replay-based regression tests on sessions recorded by the project's own processes.

``tests/data/sessions/<name>.mcap`` were recorded by ``roger daemon`` (lockstep) while
``roger sim`` (fast vision) ran one episode driven by ``roger hcc --role demonstrator``; the
goldens next to them were produced from those files by running the code. Regenerate both
with ``scripts/regenerate_test_sessions.py`` (see its docstring).
"""

from __future__ import annotations

import json
import random
from pathlib import Path
from typing import Any

import pytest
from mcap_testing import chunk_ends, messages

from roger_daemon.cli import main as roger
from roger_daemon.recording import (
    is_complete,
    read_metadata,
    recover,
    replay_session,
)
from roger_daemon.recording.compare import behaviour, behaviour_differences

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[1]
DATA = Path("tests/data/sessions")
NAMES = sorted(p.name[: -len(".golden.json")] for p in (ROOT / DATA).glob("*.golden.json"))
TOL = 1e-9


def _golden(name: str) -> dict[str, Any]:
    data: dict[str, Any] = json.loads((ROOT / DATA / f"{name}.golden.json").read_text())
    return data


@pytest.fixture(scope="module")
def replays() -> dict[str, Any]:
    """Each session replayed once (the module's tests share the results)."""
    return {name: replay_session(ROOT / DATA / f"{name}.mcap") for name in NAMES}


def test_the_sessions_are_there() -> None:
    assert len(NAMES) >= 2
    for name in NAMES:
        path = ROOT / DATA / f"{name}.mcap"
        assert path.stat().st_size < 1_000_000 and is_complete(path)
        meta = read_metadata(path)
        assert meta["created_by"] == "roger daemon" and meta["clock"] == "lockstep"
        assert _golden(name)["file"] == str(DATA / f"{name}.mcap")
    locations = {_golden(n)["recorded_with"]["location"] for n in NAMES}
    assert len(locations) == len(NAMES)  # different start locations


@pytest.mark.parametrize("name", NAMES)
def test_replay_reproduces_the_recorded_model(name: str, replays: dict[str, Any]) -> None:
    golden, res = _golden(name), replays[name]
    # every prediction the daemon published is recomputed to 1e-9 ...
    assert res.ok(TOL), res.summary(TOL)
    assert len(res.diffs) == golden["predictions_compared"] and res.unreplayable == 0
    # ... and the rebuilt model is the golden one: same pairs, experts, assignments, labels,
    # predictions on the probe inputs
    assert len(res.pairs) == golden["pairs_learned"]
    assert [p.tick for p in res.pairs[:5]] == golden["first_ticks"]
    assert [p.tick for p in res.pairs[-5:]] == golden["last_ticks"]
    want = golden["behaviour"]
    assert res.n_experts == want["n_experts"] >= 2
    assert res.assignments.tolist() == want["assignments"]
    assert {str(k): v for k, v in res.expert_labels.items()} == golden["expert_labels"]
    probes = [p["x"] for p in want["probes"]]
    assert behaviour_differences(behaviour(res.model, probes), want, TOL) == []


def test_the_goldens_catch_a_changed_learner(replays: dict[str, Any]) -> None:
    """A learner parameter off by one part in a million: replay and goldens both object."""
    name = NAMES[0]
    golden = _golden(name)
    params = dict(replays[name].params)
    params["theta_n"] *= 1 + 1e-6
    res = replay_session(ROOT / DATA / f"{name}.mcap", params=params)
    assert not res.ok(TOL) and res.mismatches(TOL)
    probes = [p["x"] for p in golden["behaviour"]["probes"]]
    assert behaviour_differences(behaviour(res.model, probes), golden["behaviour"], TOL)


@pytest.mark.parametrize("name", NAMES)
def test_log_info_is_stable(name: str, monkeypatch: pytest.MonkeyPatch,
                            capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.chdir(ROOT)
    assert roger(["log", "info", str(DATA / f"{name}.mcap")]) == 0
    assert capsys.readouterr().out == (ROOT / DATA / f"{name}.info.txt").read_text()


@pytest.mark.parametrize("name", NAMES)
def test_truncated_copies_are_recovered_with_every_complete_chunk(
    name: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    src = ROOT / DATA / f"{name}.mcap"
    data = src.read_bytes()
    full = messages(src)
    ends = chunk_ends(src)
    assert len(ends) >= 3 and sum(n for _, n in ends) == len(full)
    rnd = random.Random(f"truncate-{name}")
    points = sorted({rnd.randrange(64, len(data)) for _ in range(30)}
                    | {e for e, _ in ends} | {e - 1 for e, _ in ends} | {e + 1 for e, _ in ends})
    cut = tmp_path / "cut.mcap"
    for p in points:
        cut.write_bytes(data[:p])
        rep = recover(cut, tmp_path / "rec.mcap")
        kept = sum(n for e, n in ends if e <= p)
        assert rep.messages == kept, p
        assert messages(Path(rep.output)) == full[:kept], p
        assert is_complete(rep.output) and rep.metadata == 1 and not rep.complete
    # the command line says the same: lossy (exit 3), how much was kept
    middle = ends[len(ends) // 2][0] + 10
    cut.write_bytes(data[:middle])
    assert roger(["log", "recover", str(cut), "--out", str(tmp_path / "cli.mcap")]) == 3
    kept = sum(n for e, n in ends if e <= middle)
    assert f"kept {kept} messages" in capsys.readouterr().out
