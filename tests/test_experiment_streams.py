"""``roger experiment goal-scoring --streams``: parsing, the summary over (stream, seed), the
bundle round trip and ``roger experiment table``."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from cli_testing import in_process

from simulator.experiment.streams import CHOOSE, parse_streams, summarise
from simulator.experiment.table import markdown

ROOT = Path(__file__).resolve().parents[1]


def test_streams_parse_and_bad_lists_are_refused() -> None:
    assert parse_streams("0-4") == (0, 1, 2, 3, 4)
    assert parse_streams("3, 1") == (3, 1)
    for bad in ("", "a", "0-x", "1,1", "-1"):
        with pytest.raises(ValueError, match="--streams"):
            parse_streams(bad)


def _stream(hcc: float, roger: list[float], auto: list[float]) -> dict[str, Any]:
    return {"hcc": {"success_rate": hcc}, "oracle": {"success_rate": hcc},
            "dpa": {"success_rate": 0.0},
            "roger_seeds": [{"success_rate": r, "ari": 0.5, "experts": 9,
                             "groups": {"success_rate": hcc}} for r in roger],
            "autonomous_seeds": [{"success_rate": a} for a in auto]}


def test_summary_is_over_stream_and_seed_and_keeps_validation_apart() -> None:
    per = {0: _stream(0.8, [0.8, 0.4], [0.4, 0.0]), 1: _stream(0.5, [0.5, 0.25], [0.5, 0.5]),
           3: _stream(1.0, [0.1, 0.3], [0.2, 0.2])}
    out = summarise(per)
    s = out["summary"]["roger"]
    assert s["all"]["n"] == 6
    assert s["all"]["mean_ratio"] == pytest.approx(np.mean([1, .5, 1, .5, .1, .3]))
    assert s["all"]["worst_ratio"] == pytest.approx(0.1)
    assert s["choose_0_2"]["n"] == 4 and 3 not in CHOOSE
    assert s["validation"]["mean_ratio"] == pytest.approx(0.2)
    lo, hi = s["all"]["ci95"]
    assert lo < s["all"]["mean_ratio"] < hi
    assert out["ratio_autonomous_to_hcc"] == pytest.approx(np.mean([.5, 0, 1, 1, .2, .2]))
    assert out["summary"]["groups"]["all"]["mean_ratio"] == pytest.approx(1.0)
    table = markdown(out)
    assert "| ROGER experts + HCC transitioner | 0.75 | 0.75 | 0.20 |" in table
    assert "stream 3" in table
    split = markdown({**out, "plan": {"gates": "split"}})
    assert "| ROGER experts (split gates) + HCC transitioner | 0.75 | 0.75 | 0.20 |" in split
    assert "| ROGER experts (split gates) + learned transitions (no HCC) |" in split
    assert "(split gates)" not in table


def test_table_command_refuses_a_file_that_is_not_results(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """In this process (tests/cli_testing.py: a traceback fails the test here)."""
    bad = tmp_path / "x.json"
    bad.write_text("[1, 2]")
    good = tmp_path / "r.json"
    good.write_text(json.dumps(summarise({0: _stream(1.0, [0.5], [0.25])})))
    with in_process(capsys, monkeypatch) as run:
        proc = run("experiment", "table", str(bad), cwd=ROOT)
        assert proc.returncode == 2
        assert "not a goal-scoring results.json" in proc.stderr
        proc = run("experiment", "table", str(good), cwd=ROOT)
        assert proc.returncode == 0 and "learned transitions" in proc.stdout


@pytest.mark.integration
def test_two_streams_run_end_to_end(tmp_path: Path) -> None:
    """The protocol on two tiny streams (one location, short episodes): per-stream results,
    the summary and the bundles, in real worker processes."""
    out = tmp_path / "s"
    proc = subprocess.run(
        [sys.executable, "-m", "roger_daemon", "experiment", "goal-scoring", "--quick",
         "--streams", "0,4", "--locations", "0", "--time-limit", "10", "--per-subtask", "60",
         "--controllers", "hcc,roger,autonomous", "--jobs", "2", "--out", str(out)],
        capture_output=True, text=True, cwd=ROOT, timeout=280)
    assert proc.returncode == 0, proc.stderr[-2000:]
    res = json.loads((out / "results.json").read_text())
    assert set(res["streams"]) == {"0", "4"}
    for s in ("0", "4"):
        single = json.loads((out / f"stream-{s}" / "results.json").read_text())
        assert single["seed"] == int(s) and single["autonomous"]["trials"] == 1
        graph = single["autonomous_seeds"][0]["graph"]  # against the HCC's, labels mapped
        assert graph["edges_hcc"] > 0 and 0.0 <= graph["graph_agreement"] <= 1.0
        assert (out / f"stream-{s}" / "prepared.npz").exists()
    assert res["summary"]["autonomous"]["validation"]["n"] <= 1
    assert 0.0 <= res["autonomous_graph_agreement"] <= 1.0


def test_table_adds_the_peers_rows_from_their_results(tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    """``--peers`` appends each peer's row from a ``roger experiment peers`` results file (the
    shipped ones of docs/peers.md), and refuses a file that is not one, naming it."""
    from roger_daemon.cli import main

    root = Path(__file__).resolve().parents[1] / "docs" / "figures"
    act, dp = root / "peers" / "results-act.json", root / "peers" / "results-diffusion.json"
    assert main(["experiment", "table", str(root / "goal-scoring" / "results.json"),
                 "--peers", str(act), str(dp)]) == 0
    out = capsys.readouterr().out
    expected = json.loads(act.read_text())["peers"]["act"]
    assert (f"| ACT (LeRobot), {expected['steps']:,} steps | {expected['successes']}/"
            f"{expected['trials']} |") in out
    assert "| Diffusion Policy (LeRobot), 1,500 steps | 1/13 | 8 % (1 % - 33 %) |" in out
    bad = tmp_path / "notes.json"
    bad.write_text('{"schema": 1}')
    assert main(["experiment", "table", str(root / "goal-scoring" / "results.json"),
                 "--peers", str(bad)]) == 2
    assert f"--peers {bad}" in capsys.readouterr().err
