"""``roger experiment goal-scoring --quick``: the whole pipeline in real processes over Zenoh.

Checks the pipeline and the result schema, not the success numbers: demonstrations recorded to
MCAP and read back, the daemon/replay/offline models identical, every controller evaluated,
results.json complete, the figures written; then ``--resume`` reuses every finished job and
reproduces the same results.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from process_testing import processes_naming

from simulator.controllers.hcc import LABELS
from simulator.experiment.report import check_results

pytestmark = pytest.mark.integration

ROGER = [sys.executable, "-m", "roger_daemon"]
PNG = b"\x89PNG\r\n\x1a\n"
# the quick run and its resume take ~70 s of CPU (a sixth of the suite on a 2-core AMD EPYC):
# `make test-all` runs them; `make test` keeps the stop tests below, which start the same
# pipeline, and tests/test_experiment_inprocess.py, its in-process path
_QUICK = pytest.mark.slow


def _run(out: Path, *extra: str, timeout: float = 900.0) -> tuple[dict[str, Any], float, str]:
    t0 = time.monotonic()
    proc = subprocess.run(
        [*ROGER, "experiment", "goal-scoring", "--quick", "--out", str(out), "--jobs", "2",
         "--seed", "3", *extra],
        capture_output=True, text=True, timeout=timeout,
    )
    wall = time.monotonic() - t0
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-4000:]
    results: dict[str, Any] = json.loads((out / "results.json").read_text())
    return results, wall, proc.stdout


@pytest.fixture(scope="module")
def quick(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any], float, str]:
    out = tmp_path_factory.mktemp("goal-scoring") / "quick"
    results, wall, stdout = _run(out)
    return out, results, wall, stdout


@_QUICK
def test_quick_run_writes_the_full_schema(
    quick: tuple[Path, dict[str, Any], float, str],
) -> None:
    out, r, wall, stdout = quick
    assert check_results(r) == []
    assert r["seed"] == 3 and r["seeds"]["master"] == 3 and r["quick"] is True
    assert r["errors"] == []
    plan = r["config"]["experiment"]
    assert plan["locations"] == [0, 6] and plan["attempts"] == 1
    # the learner parameters the run used
    learner = r["config"]["learner"]
    # the paper's alpha and beta; 100 particles is the task's setting (TASK_LEARNER_OVERRIDES)
    assert (learner["alpha"], learner["beta"], learner["particles"]) == (0.5, 300, 100)
    assert r["paper"] == {"hcc": 0.69, "roger": 0.31, "dpa": 0.0, "experts": 85, "ratio": 0.45}
    for c in ("hcc", "roger", "dpa", "oracle", "groups"):
        assert r[c]["trials"] == 2
        assert 0.0 <= r[c]["ci95_low"] <= r[c]["success_rate"] <= r[c]["ci95_high"] <= 1.0
        assert sum(r[c]["failure_modes"].values()) == 2
    for c in ("hcc", "roger:0", "dpa", "oracle", "groups:0"):
        assert [row["location"] for row in r["per_location"][c]] == [0, 6]
        assert all(row["attempts"] == 1 for row in r["per_location"][c])
        assert len(r["episodes"][c]) == 2
    assert "segmentation oracle" in r["oracle"]["name"]
    (seed_row,) = r["roger_seeds"]
    assert seed_row["learner_seed"] == 3 and seed_row["trials"] == 2
    # the in-process path re-ran the first location and met the same episodes
    agree = r["paths_agree"]
    assert agree["all_same"] and {e["controller"] for e in agree["episodes"]} == {
        "hcc", "roger:0", "groups:0", "dpa"}
    # which BLAS computed, pinned to one thread (roger_daemon/blas.py)
    assert r["machine"]["blas"] and all(b["threads"] == 1 for b in r["machine"]["blas"])
    for phase in ("demonstrations", "training", "daemon_check", "evaluation", "total"):
        assert r["timings_s"][phase] >= 0
    # the terminal table was printed
    assert "Goal scoring" in stdout and "ratio ROGER / HCC" in stdout


@_QUICK
def test_quick_demonstrations_are_recorded_and_learned(
    quick: tuple[Path, dict[str, Any], float, str],
) -> None:
    from roger_daemon.recording import read_timeline

    out, r, _, _ = quick
    demo = r["demonstrations"]
    assert len(demo["episodes"]) == 2 and len(demo["mcap"]) == 2
    ticks = sum(e["ticks"] for e in demo["episodes"])
    # every simulator tick became one (perception, action) pair in the MCAP logs
    assert demo["pairs"] == ticks
    assert sum(len(read_timeline([p]).pairs) for p in demo["mcap"]) == ticks
    # downsampled to at most 150 per subtask, never more than was demonstrated
    for label, n in r["training"]["pairs_per_subtask"].items():
        assert n == min(150, demo["pairs_per_subtask"][label])
    # the model the daemon learned from the same stream, and a replay of its log, are identical
    check = r["training"]["daemon_check"]
    assert check["ok"], check
    # one machine, one BLAS thread: bit for bit (across machines `ok` allows REL_TOL)
    assert check["bit_identical"] and check["identical_state"] and check["replay_identical_state"]
    assert check["assignments_equal"] and check["expert_labels_equal"]
    assert check["experts_daemon"] == r["experts"]
    assert check["replay"]["predictions_compared"] == r["training"]["pairs"]
    # grouping: every expert has a majority label from the demonstrated subtasks
    rows = r["segmentation"]["experts_table"]
    assert sum(row["points"] for row in rows) == r["training"]["pairs"]
    assert {row["label"] for row in rows} <= set(LABELS)


@_QUICK
def test_quick_evaluation_ran_each_controller_cleanly(
    quick: tuple[Path, dict[str, Any], float, str],
) -> None:
    out, r, _, _ = quick
    tr = r["transport"]
    for c in ("hcc", "roger:0", "groups:0", "dpa"):
        assert tr[c]["sim_command_timeouts"] == 0, tr[c]
        assert tr[c]["sim_hold_ticks"] == 0, tr[c]
        assert tr[c]["sim_invalid_messages"] == 0, tr[c]
    # the transitioner got a prediction for every tick and chose experts by their labels
    assert tr["roger:0"]["controller_no_prediction"] == 0
    assert tr["roger:0"]["controller_label"] + tr["roger:0"]["controller_fallback_top"] > 0
    # merged groups, served by a daemon: one expert per group, each named by its group
    assert tr["groups:0"]["controller_no_prediction"] == 0
    assert tr["groups:0"]["controller_label"] > 0
    # the DPA node forwarded one command per simulator tick
    assert tr["dpa"]["sim_ticks"] > 0
    # ... and traced every tick it commanded: the averaging measure covers its episodes
    from simulator.experiment.dpa_node import read_trace

    traced = [len(x) for d in sorted((out / "work" / "eval" / "dpa").iterdir())
              for x, _ in read_trace(d / "dpa-trace.npz")]
    assert sum(traced) == sum(e["ticks"] for e in r["episodes"]["dpa"])
    for e in r["episodes"]["dpa"]:
        assert 0.0 <= e["averaged_share"] <= e["aliased_share"] <= 1.0
    for name in ("fig7_pca", "fig8_experts", "success_per_location"):
        assert Path(r["figures"][name]).read_bytes()[:8] == PNG
    assert (out / "models" / "roger-0" / "aibo").is_dir()
    assert (out / "models" / "groups-0" / "aibo").is_dir()
    assert (out / "training-data.npz").is_file()


@_QUICK
def test_resume_reuses_finished_jobs_and_reproduces_the_results(
    quick: tuple[Path, dict[str, Any], float, str],
) -> None:
    out, first, wall_first, _ = quick
    again, wall, stdout = _run(out, "--resume", "--no-daemon-check")
    assert "job failed" not in stdout
    assert again["per_location"] == first["per_location"]
    assert again["experts"] == first["experts"] and again["ari"] == first["ari"]
    assert again["models"] == first["models"]  # same model digests: training is deterministic
    # nothing was re-run: jobs were reused, each with the process time of its first run
    assert again["resumed_jobs"] > 0 and again["jobs_wall_s"] == first["jobs_wall_s"]


@pytest.mark.parametrize(("command", "started", "signum", "code"), [
    (("experiment", "goal-scoring"), "work/demo/loc-*/sim.log", 15, 143),
    (("experiment", "goal-scoring"), "work/demo/loc-*/sim.log", 2, 130),
    (("demo",), "demonstration/*.log", 15, 143),
    # stopped while the second daemon serves the merged groups (slow: a whole short demo)
    pytest.param(("demo", "--locations", "0", "--vision", "fast", "--time-limit", "10"),
                 "merged-transitioner/*.log", 15, 143, marks=pytest.mark.slow),
])
def test_a_stopped_run_leaves_no_process_behind(tmp_path: Path, command: tuple[str, ...],
                                                started: str, signum: int, code: int) -> None:
    """SIGTERM or Ctrl-C while the demonstrations run (or, for ``roger demo``, while its
    merged groups are served): ``roger experiment goal-scoring`` and ``roger demo`` exit 143
    or 130, and none of their processes (whose command lines name the
    output directory) survive."""
    out = tmp_path / "run"
    proc = subprocess.Popen([*ROGER, *command, "--out", str(out)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        end = time.monotonic() + 240
        while not list(out.glob(started)):
            assert proc.poll() is None and time.monotonic() < end, "no job started"
            time.sleep(0.1)
        assert processes_naming(str(out))  # a job's processes are running
        proc.send_signal(signum)
        assert proc.wait(120) == code
    finally:
        if proc.poll() is None:
            proc.kill()
    assert processes_naming(str(out)) == []
