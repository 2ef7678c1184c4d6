"""The in-process pieces of the experiment: start-pose files, the segmentation oracle, the
transitioner rules, failure modes, and that the demonstrator's labels never reach ROGER."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from cli_testing import in_process

from protocols import ExpertOutput
from roger_daemon.labels import majority_labels
from roger_daemon.learner import RogerParams
from simulator.controllers.transitioner import choose_expert, transition_command
from simulator.experiment import inprocess as ip
from simulator.experiment.pipeline import fit_segmentation_oracle, train_models
from simulator.experiment.start_poses import (
    StartPoseError,
    load_start_poses,
    parse_start_poses,
)
from simulator.experiment.training import Demonstrations, model_fingerprint
from simulator.experiment.zenoh_run import compare_paths

GOOD_TOML = """
[[pose]]
name = "corner"
robot = [1.8, -1.2, 135.0]
ball = [1.5, -0.9]

[[pose]]
robot = [-1, 0.5, 0]
ball = [-0.5, 0.5]
"""


def test_start_poses_from_toml_and_json(tmp_path: Path) -> None:
    t = tmp_path / "poses.toml"
    t.write_text(GOOD_TOML)
    poses = load_start_poses(t)
    assert [p.name for p in poses] == ["corner", "pose-1"]
    assert poses[0].robot == (1.8, -1.2, 135.0) and poses[1].ball == (-0.5, 0.5)
    j = tmp_path / "poses.json"
    j.write_text(json.dumps({"pose": [{"name": "corner", "robot": [1.8, -1.2, 135.0],
                                       "ball": [1.5, -0.9]}]}))
    (from_json,) = load_start_poses(j)
    assert (from_json.robot, from_json.ball, from_json.name) == (
        poses[0].robot, poses[0].ball, poses[0].name)


def test_the_example_held_out_poses_are_valid_and_new() -> None:
    from simulator.episodes import START_LOCATIONS

    poses = load_start_poses(Path(__file__).parents[1] / "configs" / "held-out-poses.toml")
    assert len(poses) >= 5
    known = {(s.robot, s.ball) for s in START_LOCATIONS}
    assert not any((p.robot, p.ball) in known for p in poses)


@pytest.mark.parametrize(("data", "needle"), [
    ({"poses": []}, "'pose' array"),
    ({"pose": []}, "non-empty array"),
    ({"pose": [{"robot": [0, 0, 0]}]}, "pose[0]: missing 'ball'"),
    ({"pose": [{"robot": [0, 0], "ball": [1, 0]}]}, "pose[0].robot: expected [x m, y m, "
                                                    "heading deg], got [0, 0]"),
    ({"pose": [{"robot": [0, 0, "north"], "ball": [1, 0]}]}, "heading deg"),
    ({"pose": [{"robot": [0, 0, 0], "ball": [3.0, 0]}]}, "pose[0].ball: expected a point "
                                                         "inside the field"),
    ({"pose": [{"robot": [0, 0, 0], "ball": [0.05, 0]}]}, "at least 0.15 m"),
    ({"pose": [{"robot": [0, 0, 0], "ball": [1, 0], "speed": 2}]}, "unknown key(s) ['speed']"),
])
def test_bad_start_poses_name_the_entry_the_form_and_the_value(data: object, needle: str
                                                               ) -> None:
    with pytest.raises(StartPoseError) as err:
        parse_start_poses(data, "f.toml")
    assert needle in str(err.value)


def test_bad_start_pose_file_exits_2_without_a_traceback(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """In this process (tests/cli_testing.py: a traceback fails the test here)."""
    bad = tmp_path / "bad.toml"
    bad.write_text('[[pose]]\nrobot = [0, 0, 0]\nball = [9, 0]\n')
    with in_process(capsys, monkeypatch) as run:
        proc = run("experiment", "goal-scoring", "--out", str(tmp_path / "o"),
                   "--start-poses", str(bad))
        assert proc.returncode == 2
        assert "pose[0].ball: expected a point inside the field" in proc.stderr
        assert "got [9.0, 0.0]" in proc.stderr
        missing = run("experiment", "goal-scoring", "--out", str(tmp_path / "o"),
                      "--start-poses", str(tmp_path / "none.yaml"))
        assert missing.returncode == 2 and ".toml or .json" in missing.stderr


def _e(i: int, p: float, label: str, var: float) -> ExpertOutput:
    return ExpertOutput(i, p, np.full(9, float(i)), np.full(9, var), 10, label)


def test_transitioner_rules_variance_and_gate() -> None:
    mm = (_e(1, 0.6, "aim", 0.5), _e(2, 0.3, "aim", 0.1), _e(3, 0.1, "kick", 0.01))
    assert choose_expert(mm, "aim", "variance") == (mm[1], "label")
    assert choose_expert(mm, "aim", "gate") == (mm[0], "label")
    big = (ExpertOutput(4, 0.2, np.zeros(9), np.ones(9), 500, "aim"), *mm)
    assert choose_expert(big, "aim", "support") == (big[0], "label")
    assert choose_expert(mm, "trap", "variance") == (mm[0], "fallback_top")
    y, how, expert = transition_command(mm, None, "aim", "variance")
    assert how == "label" and expert == 2 and np.all(y == 2.0)
    y, how, expert = transition_command((), np.ones(9), "aim", "variance")
    assert (how, expert) == ("fallback_mean", -1) and np.all(y == 1.0)
    with pytest.raises(ValueError, match="rule"):
        choose_expert(mm, "aim", "vote")


def test_failure_modes() -> None:
    fm = ip.failure_mode
    assert fm("goal", {}, None) == "goal"
    assert fm("timeout", {"traps": 3}, 0.1) == "stands still"
    assert fm("timeout", {}, None) == "never traps"
    assert fm("timeout", {"kicks": 2}, 5.0) == "kicks in place"
    assert fm("timeout", {"traps": 2, "traps_ok": 0}, 5.0) == "traps fail"
    assert fm("timeout", {"traps": 1, "traps_ok": 1}, 5.0) == "no kick after trap"
    assert fm("timeout", {"traps": 1, "traps_ok": 1, "kicks": 1}, 5.0) == "kicks, misses"
    assert fm("out", {}, 3.0) == "ball out"


def _stream(n: int, rng: np.random.Generator, labels: list[str]) -> Demonstrations:
    x = rng.uniform(-1, 1, (n, 3))
    y = np.where(np.array(labels)[:, None] == "a", 1.0, -1.0) + 0.1 * x[:, :2]
    return Demonstrations(x, y, labels, np.zeros(n, dtype=np.int64), np.arange(n), 0)


def test_the_demonstrators_labels_never_reach_roger() -> None:
    rng = np.random.default_rng(5)
    labels = ["a" if v > 0 else "b" for v in rng.standard_normal(60)]
    s1 = _stream(60, np.random.default_rng(1), labels)
    s2 = Demonstrations(s1.x, s1.y, list(reversed(labels)), s1.location, s1.tick, 0)
    plan = SimpleNamespace(seeds={"learner": 4}, learner_seeds=2)
    params = RogerParams(nu0=4.0, theta_w=1.0, particles=3)
    m1, u1, _ = train_models(s1, params, plan)
    m2, u2, _ = train_models(s2, params, plan)
    assert [s for s, _ in m1] == [4, 5]
    assert [model_fingerprint(m) for _, m in m1] == [model_fingerprint(m) for _, m in m2]
    assert model_fingerprint(u1) == model_fingerprint(u2)


def test_segmentation_oracle_has_one_gp_per_true_subtask() -> None:
    labels = ["a"] * 20 + ["b"] * 15 + ["a"] * 5
    s = _stream(40, np.random.default_rng(2), labels)
    gps = fit_segmentation_oracle(s, RogerParams(nu0=4.0, theta_w=1.0), seed=0)
    assert sorted(gps) == ["a", "b"]
    assert gps["a"].n_learned == 25 and gps["b"].n_learned == 15
    mean_a = gps["a"].predict_one(s.x[0]).mean
    assert np.all(mean_a > 0.5)  # learned branch "a" (outputs near +1), not the average


def test_merged_expert_groups_learn_the_points_of_each_group_of_roger_experts() -> None:
    """merge_expert_groups: one expert per majority label, learning, in stream order, exactly
    the points ROGER assigned to that label's experts (oracle: a unimap GP fed those points by
    hand predicts the same), named by its group."""
    from roger_daemon.learner import Roger, UnimapGP
    from simulator.experiment.pipeline import merge_expert_groups

    labels = ["a"] * 20 + ["b"] * 15 + ["a"] * 5
    s = _stream(40, np.random.default_rng(2), labels)
    params = RogerParams(nu0=4.0, theta_w=1.0, particles=3)
    model = Roger(d_x=3, d_y=2, params=params, seed=1)
    for x, y in zip(s.x, s.y, strict=True):
        model.learn_one(x, y)
    merged = merge_expert_groups(s, model, params, seed=0)
    assignments = np.asarray(model.assignments()).tolist()
    groups = majority_labels(assignments, labels)
    assert merged.group_of_point == [groups[k] for k in assignments]
    assert sorted(merged.labels.values()) == sorted(set(groups.values()))
    sizes = merged.model.expert_sizes()
    q = np.array([0.3, -0.2, 0.1])
    for expert, name in merged.labels.items():
        mine = [i for i, g in enumerate(merged.group_of_point) if g == name]
        assert sizes[expert] == len(mine)
        by_hand = UnimapGP(d_x=3, d_y=2, params=params, seed=0)
        for i in mine:
            by_hand.learn_one(s.x[i], s.y[i])
        ours = {e.expert_id: e for e in merged.model.predict_multimap(q)}[expert]
        np.testing.assert_allclose(ours.mean, by_hand.predict_one(q).mean, rtol=1e-9)


def test_compare_paths_reports_any_difference() -> None:
    ep = {"location": 0, "repetition": 0, "outcome": "goal", "ticks": 10, "traps": 1,
          "kicks": 1}
    same = compare_paths({"hcc": [ep]}, {"hcc": [dict(ep)]})
    assert same["all_same"]
    other = compare_paths({"hcc": [ep]}, {"hcc": [{**ep, "ticks": 11}]})
    assert not other["all_same"] and other["episodes"][0]["zenoh_ticks"] == 10
    missing = compare_paths({}, {"hcc": [ep]})
    assert not missing["all_same"]


def test_the_in_process_path_writes_results_figures_and_the_dpas_averaging(
        tmp_path: Path) -> None:
    """``--in-process --quick`` end to end (one location): results.json, the three figures,
    and every DPA episode measured for averaging (simulator/experiment/averaging.py)."""
    out = tmp_path / "run"
    proc = subprocess.run(
        [sys.executable, "-m", "roger_daemon", "experiment", "goal-scoring", "--quick",
         "--in-process", "--locations", "0", "--time-limit", "10", "--out", str(out)],
        capture_output=True, text=True, timeout=600,
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    r = json.loads((out / "results.json").read_text())
    assert r["path"] == "in-process"
    for name in ("fig7_pca", "fig8_experts", "success_per_location"):
        assert Path(r["figures"][name]).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    (dpa,) = r["episodes"]["dpa"]
    (merged,) = r["episodes"]["groups:0"]  # ROGER's experts merged per group, in-process
    assert r["groups"]["trials"] == 1 and merged["location"] == 0
    assert 0.0 <= dpa["averaged_share"] <= dpa["aliased_share"] <= 1.0
    if not dpa["success"]:
        assert r["dpa"]["averaging"]["failed_episodes_measured"] == 1
    with np.load(out / "training-data.npz") as data:  # what scripts/ablation.py reads
        assert data["x"].shape == (r["training"]["pairs"], 23)
        assert data["assignments"].shape == (r["training"]["pairs"],)
