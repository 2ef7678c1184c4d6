"""``scripts/learner_monitor.py`` (docs/performance.md, *A cross-core probe in the record*): the
learner benchmark run back to back, each run sorted by the cross-core readings of its machine
record; bad arguments exit 2."""

from __future__ import annotations

import doctest
import json
import subprocess
import sys
from pathlib import Path
from types import ModuleType

from script_testing import load_script

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "learner_monitor.py"


def _module() -> ModuleType:
    return load_script("learner_monitor", SCRIPT)


def test_the_examples_in_the_docstrings_hold() -> None:
    result = doctest.testmod(_module())
    assert result.attempted >= 4 and result.failed == 0


def test_a_state_needs_both_readings_on_one_side_of_the_line() -> None:
    state_of = _module().state_of
    assert state_of(251.0, 251.0, 250) == "far apart"
    assert state_of(250.0, 250.0, 250) == "near"  # the line itself is near
    assert state_of(400.0, 80.0, 250) == "mixed"
    assert state_of(400.0, None, 250) == "unknown"


def test_the_summary_counts_each_state_and_leaves_failed_runs_out() -> None:
    runs = [{"updates_per_s": 2400.0, "update_p99_ms": 0.9, "state": "near"},
            {"updates_per_s": 1999.9, "update_p99_ms": 2.1, "state": "far apart"},
            {"updates_per_s": 2000.0, "update_p99_ms": 1.2, "state": "far apart"},
            {"time": "00:00:00", "failed": 1, "stderr": ""}]
    summary = _module().summarise(runs, 2000.0)
    assert summary["all"] == {"runs": 3, "min": 1999.9, "median": 2000.0, "max": 2400.0,
                              "below_target": 1, "worst_p99_ms": 2.1}
    assert summary["far apart"]["runs"] == 2 and summary["far apart"]["below_target"] == 1
    assert summary["near"]["worst_p99_ms"] == 0.9
    assert "mixed" not in summary and "unknown" not in summary


def test_one_run_is_measured_and_sorted() -> None:
    out = subprocess.run([sys.executable, str(SCRIPT), "--minutes", "0", "--points", "100",
                          "--json"],
                         capture_output=True, text=True, timeout=1800, check=True)
    report = json.loads(out.stdout)
    assert report["failed"] == 0 and len(report["runs"]) == 1
    run = report["runs"][0]
    assert run["updates_per_s"] > 0 and run["update_p99_ms"] > 0
    start, end = run["cross_core_ns"]
    assert run["state"] == _module().state_of(start, end, 250.0)
    assert report["summary"]["all"]["runs"] == 1


def test_bad_arguments_exit_2_naming_the_value() -> None:
    bad = subprocess.run([sys.executable, str(SCRIPT), "--far-ns", "-1"],
                         capture_output=True, text=True, timeout=600)
    assert bad.returncode == 2
    assert "argument --far-ns: expected a finite number >= 0, got '-1'" in bad.stderr
    nan = subprocess.run([sys.executable, str(SCRIPT), "--minutes", "nan"],
                         capture_output=True, text=True, timeout=600)
    assert nan.returncode == 2
    assert "argument --minutes: expected a finite number >= 0, got 'nan'" in nan.stderr
