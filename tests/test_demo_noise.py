"""Perturbed demonstrations (simulator/controllers/demo_noise.py): the demonstrator's command is
recorded, the disturbed one executed; ``--demo-noise 0`` is the paper's protocol exactly."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pytest
from cli_testing import in_process
from hypothesis import given, settings
from hypothesis import strategies as st

from protocols import Action, Command, Perception
from protocols.aibo import ACTION_RANGES, DIMS
from simulator import transport
from simulator.controllers import hcc_node
from simulator.controllers.demo_noise import NOISY, DemoNoise, seeded
from simulator.controllers.hcc import HCC
from simulator.experiment.inprocess import _Recorder
from simulator.transport import StopFlag

LOW = np.array([lo for lo, _ in ACTION_RANGES])
HIGH = np.array([hi for _, hi in ACTION_RANGES])


@settings(max_examples=25, deadline=None)
@given(scale=st.floats(0.0, 0.5), hold=st.integers(1, 20), seed=st.integers(0, 1000))
def test_the_noise_is_held_clipped_and_only_on_walking_and_head(scale: float, hold: int,
                                                                seed: int) -> None:
    noise = DemoNoise(scale, np.random.default_rng(seed), hold=hold)
    y = np.random.default_rng(seed + 1).uniform(LOW, HIGH)
    out = [noise(y) for _ in range(2 * hold + 1)]
    quiet = [i for i in range(DIMS.y) if i not in NOISY]
    for o in out:
        assert np.array_equal(o[quiet], y[quiet])  # tail and motion indicator untouched
        assert np.all(o >= LOW) and np.all(o <= HIGH)
    for k in range(1, hold):  # one disturbance per hold ticks
        assert np.array_equal(out[k], out[0])
    if scale == 0.0:
        assert all(np.array_equal(o, y) for o in out)
    again = DemoNoise(scale, np.random.default_rng(seed), hold=hold)
    assert all(np.array_equal(a, again(y)) for a in out)  # seeded: same draws


def test_the_spread_is_scale_times_each_range() -> None:
    noise = DemoNoise(0.1, np.random.default_rng(0), hold=1)
    mid = 0.5 * (LOW + HIGH)
    draws = np.array([noise(mid) for _ in range(4000)])
    sd = draws.std(axis=0)
    for i in NOISY:
        assert sd[i] == pytest.approx(0.1 * (HIGH[i] - LOW[i]), rel=0.1)


@pytest.mark.parametrize("scale", [-0.1, 0.6, float("nan")])
def test_a_bad_scale_is_refused_naming_it(scale: float) -> None:
    with pytest.raises(ValueError, match="demonstration noise"):
        DemoNoise(scale, np.random.default_rng(0))


def test_the_recorder_learns_the_demonstrators_command_and_executes_the_disturbed_one() -> None:
    """The pair's action is the HCC's decision; the robot gets the disturbed command and the
    HCC's odometry (its remembered ball bearing) follows the executed turn."""
    x = np.zeros(DIMS.x)
    x[[2, 5, 8, 11, 14, 17]] = -1.0  # nothing seen: the HCC seeks, turning
    plain, noisy = HCC(), HCC()
    quiet = _Recorder(plain)
    rec = _Recorder(noisy, DemoNoise(0.3, np.random.default_rng(3), hold=5))
    quiet.reset()
    rec.reset()
    for _ in range(12):
        y0, _ = quiet.act(x)
        y1, _ = rec.act(x)
    assert np.array_equal(np.array(rec.y), np.array(quiet.y))  # same decisions recorded
    assert not np.array_equal(y1, y0)
    assert noisy.ball_bearing != plain.ball_bearing  # odometry of the executed turns


@pytest.mark.parametrize("argv, message", [
    (["--demo-noise", "0.7"], "--demo-noise 0.7: must be in [0, 0.5]"),
    (["--in-process", "--demo-noise", "-0.1"], "--demo-noise -0.1: must be in [0, 0.5]"),
])
def test_the_command_refuses_bad_noise_naming_it(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                 monkeypatch: pytest.MonkeyPatch, argv: list[str],
                                                 message: str) -> None:
    out = tmp_path / "run"
    with in_process(capsys, monkeypatch) as run:
        ran = run("experiment", "goal-scoring", "--out", str(out), "--plan", *argv)
    assert ran.returncode == 2, ran.stderr
    assert message in ran.stderr and "Traceback" not in ran.stderr
    assert not out.exists()


def _hcc_args(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    hcc_node.configure(parser)
    return parser.parse_args(list(argv))


def test_roger_hcc_publishes_the_fsms_action_and_drives_the_robot_with_it_disturbed(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """``roger hcc --demo-noise``: ``action`` is the FSM's decision, ``command`` the disturbed
    vector, and the FSM is told the executed one; a new episode redraws the disturbance."""
    sent: list[object] = []
    monkeypatch.setattr(hcc_node, "put", lambda _pub, msg: sent.append(msg))
    monkeypatch.setattr(transport, "put", lambda _pub, msg: sent.append(msg))
    args = _hcc_args("--demo-noise", "0.3", "--demo-noise-seed", "5")
    n = hcc_node.HCCNode(args, HCC(), StopFlag(install=False), seeded(0.3, 5))
    n.pub_act, n.pub_cmd = object(), object()  # type: ignore[assignment]
    twin, twin_noise = HCC(), seeded(0.3, 5)
    assert twin_noise is not None
    x = np.zeros(DIMS.x)
    x[[2, 5, 8, 11, 14, 17]] = -1.0  # nothing seen: the HCC seeks on its remembered bearing
    ticks = [(k, k / 30) for k in range(20)] + [(0, 0.0)] + [(k, k / 30) for k in range(1, 8)]
    disturbed = 0
    for tick, t in ticks:
        n._on_message(Perception("aibo", tick, t, x=x))
        if t == 0.0:
            twin.reset()
            twin_noise.reset()
        y, label = twin.decide(x)
        executed = twin_noise(y)
        twin.commit(executed)
        action, command = sent[-2:]
        assert isinstance(action, Action) and isinstance(command, Command)
        assert np.array_equal(action.y, y) and action.label == label
        assert np.array_equal(command.y, executed)
        assert command.source == f"hcc:demonstrator:{label}"
        disturbed += not np.array_equal(command.y, action.y)
    assert disturbed == len(ticks)
    assert n.hcc.ball_bearing == twin.ball_bearing != HCC().ball_bearing


@pytest.mark.parametrize("argv, message", [
    (["--demo-noise", "0.7"], "--demo-noise 0.7: demonstration noise must be in [0, 0.5]"),
    (["--role", "transitioner", "--demo-noise", "0.1"],
     "--demo-noise 0.1: only the demonstrator is disturbed, not --role transitioner"),
])
def test_roger_hcc_refuses_bad_noise_naming_it(capsys: pytest.CaptureFixture[str],
                                              monkeypatch: pytest.MonkeyPatch, argv: list[str],
                                              message: str) -> None:
    with in_process(capsys, monkeypatch) as run:
        ran = run("hcc", *argv)
    assert ran.returncode == 2, ran.stderr
    assert message in ran.stderr and "Traceback" not in ran.stderr


def test_the_zenoh_paths_demonstrators_are_disturbed_per_location(tmp_path: Path) -> None:
    """``--demo-noise`` on the Zenoh path: each location's ``roger hcc`` demonstrator gets
    the noise and a seed of its own (fixed by the demonstration seed), the evaluation's
    controllers none; without noise the jobs are as before (their resume identity too)."""
    from simulator.controllers.demo_noise import location_seed
    from simulator.experiment.goal_plan import configure, plan_from_args
    from simulator.experiment.goal_scoring import _demo_jobs
    from simulator.experiment.jobs import _noise_args

    parser = argparse.ArgumentParser()
    configure(parser)
    plan = plan_from_args(parser.parse_args(["--out", str(tmp_path), "--demo-noise", "0.1"]))
    jobs = _demo_jobs(plan)
    seeds = [location_seed(plan.seeds["demo_sim"], j.locations[0]) for j in jobs]
    assert len(set(seeds)) == len(jobs) > 1
    assert seeds == [location_seed(plan.seeds["demo_sim"], j.locations[0]) for j in jobs]
    for job, seed in zip(jobs, seeds, strict=True):
        assert _noise_args(job) == ["--demo-noise", "0.1", "--demo-noise-seed", str(seed)]
        assert job.spec()["demo_noise"] == 0.1
    quiet = _demo_jobs(plan_from_args(parser.parse_args(["--out", str(tmp_path)])))
    assert all(_noise_args(j) == [] and "demo_noise" not in j.spec() for j in quiet)


def test_the_recorder_keeps_what_was_executed_beside_what_was_demonstrated() -> None:
    x = np.zeros(DIMS.x)
    x[[2, 5, 8, 11, 14, 17]] = -1.0
    rec = _Recorder(HCC(), DemoNoise(0.3, np.random.default_rng(4), hold=3))
    rec.reset()
    sent = [rec.act(x)[0] for _ in range(9)]
    assert all(np.array_equal(a, b) for a, b in zip(rec.executed, sent, strict=True))
    assert not any(np.array_equal(e, y) for e, y in zip(rec.executed, rec.y, strict=True))
    quiet = _Recorder(HCC())
    quiet.reset()
    quiet.act(x)
    assert np.array_equal(quiet.executed[0], quiet.y[0])


def test_the_learned_fsms_memories_follow_the_executed_turns_and_y_picks_the_state() -> None:
    """fit_fsm(executed=...): the transitions' features come from memories advanced by what
    the robot executed (its odometry, as when it acts), the states from the demonstrated
    command; without it the demonstrated command is the executed one."""
    from roger_daemon.fsm import LearnedFSM, aibo_memory, fit_fsm
    from roger_daemon.learner.prediction import MultimapTable

    class TwoExperts:
        def predict_table(self, x: np.ndarray) -> tuple[None, MultimapTable]:
            means = np.zeros((2, DIMS.y))
            means[1, 2] = 1.0  # expert 7 turns
            return None, MultimapTable([3, 7], [0.5, 0.5], means, np.full((2, DIMS.y), 0.01),
                                       [5, 5])

    x = np.zeros((60, DIMS.x))
    x[:, [2, 5, 8, 11, 14, 17]] = -1.0  # nothing seen: the bearings are carried by the turns
    x[:5, 2] = 1.0  # the ball seen at first, then lost
    y = np.zeros((60, DIMS.y))
    y[30:, 2] = 1.0  # the demonstrator turns from tick 30 on: expert 7
    executed = y.copy()
    executed[:, 2] += 0.8  # the robot turned more than it was told
    starts = np.zeros(60, dtype=bool)
    starts[0] = True
    spec = aibo_memory()
    got = fit_fsm(TwoExperts(), x, y, starts, spec, executed=executed)
    want = LearnedFSM(spec)
    for t in range(60):
        want.observe(x[t], executed[t], 7 if t >= 30 else 3, bool(starts[t]))
    plain = fit_fsm(TwoExperts(), x, y, starts, spec)
    same = fit_fsm(TwoExperts(), x, y, starts, spec, executed=y)
    for k, v in want.state_dict().items():
        assert np.array_equal(got.state_dict()[k], v), k
    assert all(np.array_equal(plain.state_dict()[k], v) for k, v in same.state_dict().items())
    assert not np.array_equal(plain.state_dict()["transitions.mu"],
                              got.state_dict()["transitions.mu"])
    with pytest.raises(ValueError, match="executed"):
        fit_fsm(TwoExperts(), x, y, starts, spec, executed=executed[:10])


def test_perturbed_demonstrations_keep_both_commands_and_the_quiet_ones_only_y() -> None:
    """``demonstrate`` in the simulator (pybullet DIRECT, 2 s episodes): with noise the
    stream carries the executed commands beside the demonstrated ones, differing on the
    walking and head entries only; without noise ``executed`` is None (``y`` was executed)."""
    from types import SimpleNamespace

    from simulator.experiment import inprocess as ip
    from simulator.experiment.pipeline import make_hcc, make_sim

    plan = SimpleNamespace(task_config=None, vision="fast", time_limit=2.0)
    sim = make_sim(plan)
    try:
        noisy, _ = ip.demonstrate(sim, make_hcc(plan), [0], 1, 0, noise=seeded(0.1, 0))
        quiet, _ = ip.demonstrate(sim, make_hcc(plan), [0], 1, 0)
    finally:
        sim.close()
    assert quiet.executed is None
    assert noisy.executed is not None and noisy.executed.shape == noisy.y.shape
    moved = np.flatnonzero(np.any(noisy.executed != noisy.y, axis=0)).tolist()
    assert moved and set(moved) <= set(NOISY)
    assert noisy.subset(np.arange(5)).executed is not None
