"""``roger model fsm``: the learned automaton printed, as JSON and as a picture; and the
experiment's transition-graph agreement with the HCC's (simulator/experiment/fsm_graph.py)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from cli_testing import in_process

from roger_daemon.fsm import LearnedFSM, aibo_memory
from roger_daemon.fsm.inspect import describe, format_fsm
from simulator.experiment.fsm_graph import graph_agreement, hcc_edges

ROOT = Path(__file__).resolve().parents[1]


def _fsm(states: list[int], seed: int = 0) -> LearnedFSM:
    """A learned FSM over a made-up state sequence (features from random perceptions)."""
    rng = np.random.default_rng(seed)
    fsm = LearnedFSM(aibo_memory())
    for k, s in enumerate(states):
        x = rng.uniform(-1, 1, 23)
        x[2] = 0.5 if s == 1 else -1.0  # the ball is seen only in state 1
        fsm.observe(x, rng.uniform(-0.1, 0.1, 9), s, episode_start=k == 0)
    return fsm


SEQ = [0] * 30 + [1] * 20 + [2] * 10 + [0] * 30 + [1] * 25 + [3] * 5 + [2] * 10


def test_describe_counts_states_transitions_and_their_conditions() -> None:
    desc = describe(_fsm(SEQ))
    states = {s["id"]: s for s in desc["states"]}
    assert set(states) == {0, 1, 2, 3}
    assert states[0]["ticks"] == 60 and states[0]["leaves"] == 2
    edges = {(t["from"], t["to"]): t for t in desc["transitions"]}
    assert edges[(0, 1)]["count"] == 2 and edges[(-1, 0)]["count"] == 1  # the episode start
    assert edges[(0, 1)]["p"] == pytest.approx(2 / 60, abs=1e-4)
    # the switch into state 1 is where the ball appears: its first condition says so
    assert edges[(0, 1)]["conditions"][0]["feature"].startswith("ball_")
    text = format_fsm(desc)
    assert "4 states" in text and "0 -> 1" in text


def test_roger_model_fsm_prints_and_writes(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """In this process (tests/cli_testing.py: a traceback fails the test here)."""
    state = _fsm(SEQ).state_dict()
    np.savez(tmp_path / "s.npz", **{f"fsm.{k}": v for k, v in state.items()})
    with in_process(capsys, monkeypatch) as run:
        out = run("model", "fsm", str(tmp_path / "s.npz"), "--png", str(tmp_path / "f.png"),
                  cwd=ROOT)
        assert out.returncode == 0, out.stderr
        assert "learned transitions: 4 states" in out.stdout
        as_json = run("model", "fsm", str(tmp_path / "s.npz"), "--json")
        desc = json.loads(as_json.stdout)
        assert desc["kind"] == "roger.fsm" and len(desc["states"]) == 4
        assert (tmp_path / "f.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        bad = run("model", "fsm", str(tmp_path / "none.npz"))
        assert bad.returncode == 2 and "none.npz" in bad.stderr


def test_graph_agreement_maps_experts_to_majority_labels() -> None:
    labels = ["seek"] * 30 + ["trap"] * 20 + ["kick"] * 10
    starts = [k == 0 for k in range(60)]
    assert hcc_edges(labels, starts) == {("seek", "trap"): 1, ("trap", "kick"): 1}
    # experts 0 (seek), 1 (trap), 2 and 3 (kick): the learned 1 -> 3 -> 2 is trap -> kick,
    # then a same-label switch; 2 -> 0 (kick -> seek) is an edge the HCC never made
    fsm = _fsm([0] * 10 + [1] * 10 + [3] * 5 + [2] * 5 + [0] * 5)
    g = graph_agreement(fsm, {0: "seek", 1: "trap", 2: "kick", 3: "kick"}, labels, starts)
    assert g["edges_hcc"] == 2 and g["edges_learned"] == 3  # seek->trap, trap->kick, kick->seek
    assert g["precision"] == pytest.approx(2 / 3, abs=1e-3) and g["recall"] == 1.0
    assert g["graph_agreement"] == pytest.approx(0.8, abs=1e-3)
    assert g["same_label_switch_share"] == pytest.approx(1 / 4, abs=1e-3)
    perfect = graph_agreement(_fsm([0] * 10 + [1] * 10 + [2] * 5), {0: "seek", 1: "trap",
                                                                    2: "kick"}, labels, starts)
    assert perfect["graph_agreement"] == 1.0 and perfect["missing_hcc_edges"] == []
