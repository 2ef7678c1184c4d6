"""The experiment's pieces without the simulator: plan, checkpoints the daemon resumes, labels,
the result schema, job reuse, and the DPA node over real Zenoh."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from protocols.messages import Dims
from roger_daemon.learner import Roger, RogerParams, UnimapGP
from simulator.experiment.goal_plan import configure, plan_from_args
from simulator.experiment.goal_scoring import learner_params
from simulator.experiment.jobs import EpisodeJob, load_finished
from simulator.experiment.metrics import majority_labels
from simulator.experiment.report import check_results
from simulator.experiment.training import label_state, write_model_checkpoint


def _args(*argv: str) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    configure(p)
    return p.parse_args(["--out", "x", *argv])


def test_plan_defaults_are_the_papers_protocol() -> None:
    plan = plan_from_args(_args())
    assert plan.locations == tuple(range(13)) and plan.attempts == 3
    assert plan.per_subtask == 1000 and plan.time_limit == 60.0 and plan.vision == "fast"
    assert plan.controllers == ("hcc", "roger", "dpa", "oracle", "groups", "autonomous")
    assert plan.daemon_check
    assert plan.shots == 10 and plan.learner_seeds == 3 and plan.rule == "mixture"
    assert not plan.in_process
    assert plan.seeds["master"] == 0 and plan.seeds["eval_sim"] != plan.seeds["demo_sim"]
    from roger_daemon.config import parse_config

    # the daemon's defaults, with the task's coarser novelty test (docs/goal-scoring.md)
    daemon = parse_config({}).robots[0].params
    assert learner_params(plan) == daemon.replace(novelty_threshold=1e-3, particles=100)


def test_quick_presets_and_overrides() -> None:
    plan = plan_from_args(_args("--quick", "--seed", "7", "--attempts", "2"))
    assert plan.quick and plan.locations == (0, 6) and plan.attempts == 2
    assert plan.per_subtask == 150 and plan.time_limit == 20.0 and plan.vision == "fast"
    assert plan.seeds["learner"] == 7
    assert plan.shots == 1 and plan.learner_seeds == 1
    plan = plan_from_args(_args("--set", "learner.lambda0=0.01", "--set", "learner.alpha=2"))
    params = learner_params(plan)
    assert params.lambda0 == 0.01 and params.alpha == 2.0 and params.beta == 300
    paper = learner_params(plan_from_args(_args("--preset", "paper")))
    # the paper's literal numbers, every lever off (nu0 = 24: the value for its 23 inputs)
    assert paper == RogerParams().for_dims(23) and paper.nu0 == 24.0


def test_bad_arguments_are_refused() -> None:
    with pytest.raises(ValueError, match="unknown controller"):
        plan_from_args(_args("--controllers", "hcc,nope"))
    with pytest.raises(ValueError, match="learner.KEY"):
        plan_from_args(_args("--set", "daemon.clock=realtime"))
    with pytest.raises(ValueError, match="location"):
        plan_from_args(_args("--locations", "13"))
    with pytest.raises(ValueError, match="learner.alpha"):
        learner_params(plan_from_args(_args("--set", "learner.alpha=-1")))
    with pytest.raises(ValueError, match="--shots"):
        plan_from_args(_args("--shots", "0"))
    with pytest.raises(ValueError, match="learner.preset"):
        learner_params(plan_from_args(_args("--preset", "nope")))


def test_label_codes_follow_the_experiments_tie_rule() -> None:
    from roger_daemon.labels import majority_labels_coded as daemon_majority

    labels = ["trap", "aim", "seek", "seek", "kick", "aim"]
    assign = np.array([0, 0, 1, 1, 2, 2])  # expert 0 and 2 are ties
    arr = label_state(labels).to_arrays(Dims(23, 9))  # as the checkpoint stores it
    vocab = [str(s) for s in arr["label_vocab"]]
    assert vocab == sorted(vocab)
    theirs = daemon_majority(assign, arr["label_codes"], vocab)
    assert theirs == majority_labels(assign.tolist(), labels) == {0: "aim", 1: "seek", 2: "aim"}


def _trained(n: int = 120) -> tuple[Roger, UnimapGP, np.ndarray, list[str]]:
    rng = np.random.default_rng(0)
    x = rng.uniform(-1, 1, size=(n, 23))
    y = np.zeros((n, 9))
    y[:, 0] = np.sign(x[:, 0])
    labels = ["seek" if v < 0 else "trap" for v in x[:, 0]]
    model = Roger(23, 9, RogerParams(beta=20, particles=3), seed=1)
    base = UnimapGP(23, 9, RogerParams(beta=20, particles=3), seed=1)
    for xi, yi in zip(x, y, strict=True):
        model.learn_one(xi, yi)
        base.learn_one(xi, yi)
    return model, base, x, labels


def test_the_daemon_resumes_the_written_checkpoints_with_their_labels(tmp_path: Path) -> None:
    from roger_daemon.config import load_config
    from roger_daemon.daemon.main import build_robot

    model, base, x, labels = _trained()
    params = RogerParams(beta=20, particles=3)
    for sub, m, kind in (("roger", model, "roger"), ("dpa", base, "unimap")):
        path, meta = write_model_checkpoint(tmp_path / sub, m, labels, model_kind=kind, seed=1,
                                            params=params)
        assert path.is_file() and meta.updates == len(labels)
        cfg = load_config(None, [
            f'checkpoint.dir="{tmp_path / sub}"', "daemon.mode=predict",
            "learner.beta=20", "learner.particles=3",
        ])
        robot = cfg.robots[0]
        rt, resumed = build_robot(cfg, robot, fresh=False)
        assert resumed == str(path)
        assert rt.updates == len(labels) and rt.model.n_experts == m.n_experts
        np.testing.assert_array_equal(rt.model.assignments(), m.assignments())
        np.testing.assert_array_equal(rt.model.predict_one(x[3]).mean, m.predict_one(x[3]).mean)
        assert rt.expert_labels() == majority_labels(list(m.assignments()), labels)
    with pytest.raises(ValueError, match="labels"):
        write_model_checkpoint(tmp_path / "bad", model, labels[:-1], model_kind="roger", seed=1,
                               params=params)


def test_check_results_names_what_is_missing() -> None:
    problems = check_results({"hcc": {"success_rate": 0.5, "trials": 0}, "purity": 1.5})
    assert "hcc.trials < 1" in problems and "hcc.ci95_low missing" in problems
    assert "missing controller block 'roger'" in problems and "experts missing" in problems
    assert any(p.startswith("purity") for p in problems)


def test_load_finished_requires_the_same_job(tmp_path: Path) -> None:
    job = EpisodeJob("hcc", (0,), 2, 5, 20.0, "fast", tmp_path)
    assert load_finished(job) is None
    (tmp_path / "sim.json").write_text(json.dumps({
        "episodes": [{"location": 0, "outcome": "goal"}] * 2, "summary": {"ticks": 9}}))
    (tmp_path / "job.json").write_text(json.dumps({"spec": job.spec(), "wall_s": 1.5,
                                                   "mcap": []}))
    done = load_finished(job)
    assert done is not None and done.summary == {"ticks": 9} and done.wall_s == 1.5
    other = EpisodeJob("hcc", (0,), 2, 6, 20.0, "fast", tmp_path)  # another seed
    assert load_finished(other) is None
    roger = EpisodeJob("roger", (0,), 2, 5, 20.0, "fast", tmp_path, model_digest="abc")
    assert load_finished(roger) is None


@pytest.mark.integration
def test_dpa_node_executes_the_prediction_mean(tmp_path: Path) -> None:
    """``roger experiment dpa`` turns prediction(t) into command(t) with the same mean."""
    import zenoh

    from protocols import Command, EpisodeEvent, Prediction, decode, encode, keys
    from simulator.experiment.procs import free_port
    from simulator.transport import loopback_config

    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    proc = subprocess.Popen(
        [sys.executable, "-m", "roger_daemon", "experiment", "dpa", "--connect", ep,
         "--exit-when-done", "--stats", str(tmp_path / "dpa.json")],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        session = zenoh.open(loopback_config(listen=[ep]))
        got: list[Command] = []
        session.declare_subscriber(
            keys.command("aibo"),
            lambda s: got.append(decode("command", s.payload.to_bytes())),  # type: ignore[arg-type]
        )
        pub_p = session.declare_publisher(keys.prediction("aibo"))
        pub_e = session.declare_publisher(keys.episode("aibo"))
        mean = np.linspace(-0.5, 0.5, 9)
        deadline = time.monotonic() + 120
        tick = 0
        while not got and time.monotonic() < deadline:  # until the node is connected
            pub_p.put(encode(Prediction("aibo", tick, 0.0, mean=mean, var=np.ones(9),
                                        expert=0)))
            time.sleep(0.1)
            tick += 1
        assert got, "no command from the DPA node"
        cmd = got[0]
        np.testing.assert_array_equal(cmd.y, mean)
        assert cmd.source == "dpa:unimap" and cmd.tick < tick
        pub_e.put(encode(EpisodeEvent("aibo", tick, 0.0, event="end", episode=1,
                                      data={"run_complete": True})))
        out, err = proc.communicate(timeout=120)
        session.close()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, err[-2000:]
    stats = json.loads(out.strip().splitlines()[-1])
    assert stats["commands"] == stats["predictions"] >= 1
    assert json.loads((tmp_path / "dpa.json").read_text()) == stats


def test_evaluation_jobs_cover_every_controller_and_location_once() -> None:
    from simulator.experiment.goal_scoring import EVAL_LOCATIONS_PER_JOB, _eval_jobs

    plan = plan_from_args(_args())
    jobs = _eval_jobs(plan, Path("models"), learner_params(plan), {})
    seen = [(j.key, loc) for j in jobs for loc in j.locations]
    keys = {"dpa", "hcc", "roger:0", "roger:1", "roger:2", "groups:0", "groups:1", "groups:2"}
    assert sorted(seen) == sorted((k, loc) for k in keys for loc in range(13))
    assert all(1 <= len(j.locations) <= EVAL_LOCATIONS_PER_JOB for j in jobs)
    assert len({j.workdir for j in jobs}) == len(jobs)  # one directory per job
    assert len(jobs) == 8 * 3  # 13 locations in 3 chunks per controller
    # merged groups are one-particle ROGER models, served by the daemon like ROGER's experts
    merged = [j for j in jobs if j.key.startswith("groups:")]
    assert {j.controller for j in merged} == {"roger"}
    assert {j.learner["particles"] for j in merged} == {1}
    assert {j.checkpoint_dir for j in merged} == {Path("models") / f"groups-{k}" for k in range(3)}


def test_a_stop_signalled_while_a_child_starts_stops_that_child_too() -> None:
    """SIGTERM handled between ``Popen`` and tracking the child (the main thread inside
    ``Children.spawning``) is carried out once the child is tracked: it is terminated and
    the command exits 143, instead of leaving it running (a ``roger demo`` stopped as its
    first controller started did)."""
    import signal

    from simulator.experiment.procs import Children

    children = Children()
    child: subprocess.Popen[bytes] | None = None
    try:
        with pytest.raises(SystemExit) as stop, children.spawning():
            child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
            children.on_signal(signal.SIGTERM)  # the handler, as if it ran right after fork
            assert child.poll() is None and not children.stopping  # deferred: not yet
            children.add(child)
        assert stop.value.code == 143 and children.stopping and child is not None
        assert child.wait(30) == -signal.SIGTERM
        with pytest.raises(KeyboardInterrupt):
            children.on_signal(signal.SIGINT)  # outside a start: at once
    finally:
        if child is not None and child.poll() is None:
            child.kill()
