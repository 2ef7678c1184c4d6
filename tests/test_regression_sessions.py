"""Replay-based regression tests on sessions recorded by the project's own processes.

``tests/data/sessions/<name>.mcap`` were recorded by ``roger daemon`` (lockstep) while
``roger sim`` (fast vision) ran one episode driven by ``roger hcc --role demonstrator``; the
goldens next to them were produced from those files by running the code. Regenerate both
with ``scripts/regenerate_test_sessions.py`` (see its docstring).
"""

from __future__ import annotations

import dataclasses
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
)
from roger_daemon.replay import replay_session
from roger_daemon.replay.compare import REL_TOL, behaviour, behaviour_differences
from roger_daemon.replay.session import ROUND_OFF_MARGIN, DecisionMargin

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[1]
DATA = Path("tests/data/sessions")
NAMES = sorted(p.name[: -len(".golden.json")] for p in (ROOT / DATA).glob("*.golden.json"))
TOL = REL_TOL  # structure exactly, floats within the cross-kernel tolerance


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
    # every prediction the daemon published is recomputed (bit for bit on the recording's
    # machine, within REL_TOL on another BLAS kernel) ...
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
    """A learner parameter off by one part in a million is no longer bit-identical; off by one
    part in ten thousand, replay and goldens both object beyond the cross-kernel tolerance."""
    name = NAMES[0]
    golden = _golden(name)
    params = dict(replays[name].params)
    params["theta_n"] *= 1 + 1e-6
    res = replay_session(ROOT / DATA / f"{name}.mcap", params=params)
    assert not res.bit_identical() and res.verdict(TOL) != "bit-identical"
    params["theta_n"] = replays[name].params["theta_n"] * (1 + 1e-4)
    res = replay_session(ROOT / DATA / f"{name}.mcap", params=params)
    assert not res.ok(TOL) and res.mismatches(TOL) and res.verdict(TOL) == "MISMATCH"
    probes = [p["x"] for p in golden["behaviour"]["probes"]]
    assert behaviour_differences(behaviour(res.model, probes), golden["behaviour"], TOL)


def test_a_structural_divergence_is_located_with_its_closest_decision(
    replays: dict[str, Any],
) -> None:
    """A different learner (alpha doubled) changes the segmentation: the replay names the
    first prediction whose structure differs and the replayed learner's closest decision
    before it, and says whether round-off could explain it (here it cannot)."""
    name = NAMES[0]
    params = dict(replays[name].params)
    params["alpha"] *= 2
    res = replay_session(ROOT / DATA / f"{name}.mcap", params=params)
    div = res.first_divergence()
    assert div is not None
    st = div["first_structure_divergence"]
    assert st is not None and st["kind"] == "structure"
    k = next(i for i, d in enumerate(res.diffs) if not d.structure_match)
    assert (res.diffs[k].tick, res.diffs[k].updates) == (st["tick"], st["updates"])
    assert all(d.structure_match for d in res.diffs[:k])
    c = st["closest_decision"]
    assert c["kind"] in {"resampling", "novelty", "map_particle", "expert_choice"}
    assert 0.0 <= c["margin"] and c["updates"] <= st["updates"]
    assert st["round_off_can_explain"] is (c["margin"] < ROUND_OFF_MARGIN) is False
    # the replay of the recorded learner has no structural divergence (bit for bit on the
    # recording machine's kernel, within REL_TOL on another)
    same = replays[name].first_divergence()
    assert same is None or same["first_structure_divergence"] is None


def test_a_near_tie_before_a_divergence_is_called_round_off(replays: dict[str, Any]) -> None:
    """The verdict follows the margins: the same divergence preceded by a decision 1e-12
    from its boundary is one that another BLAS kernel's round-off can explain."""
    name = NAMES[0]
    params = dict(replays[name].params)
    params["alpha"] *= 2
    res = replay_session(ROOT / DATA / f"{name}.mcap", params=params)
    st = res.first_divergence()["first_structure_divergence"]  # type: ignore[index]
    tie = DecisionMargin(st["segment"], st["updates"], "resampling", 1e-12)
    tied = dataclasses.replace(res, margins=[*res.margins, tie])
    st2 = tied.first_divergence()["first_structure_divergence"]  # type: ignore[index]
    assert st2["closest_decision"] == {"kind": "resampling", "updates": st["updates"],
                                       "margin": 1e-12}
    assert st2["round_off_can_explain"] is True


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
