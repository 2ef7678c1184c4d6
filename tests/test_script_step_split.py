"""``scripts/learner_step_split.py`` (docs/performance.md, *The slow spells are the two cores
far apart*): it times the benchmark's steps in two parts, the experts' kernels and the rest,
on every core and on one thread, and rejects bad arguments with exit 2."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "learner_step_split.py"


def test_one_sample_splits_each_step_into_kernels_and_the_rest() -> None:
    # a model of 60 points and 10 timed steps: enough for the kernels to run inside the steps
    out = subprocess.run([sys.executable, str(SCRIPT), "--minutes", "0", "--steps", "10",
                          "--warm-points", "60", "--json"],
                         capture_output=True, text=True, timeout=900, check=True)
    report = json.loads(out.stdout)
    assert len(report["samples"]) == 1 and report["steps_per_timing"] == 10
    for label in ("all_cores", "one_thread"):
        part = report["samples"][0][label]
        assert 0 < part["kernel_us"] < part["step_us"]  # the kernels ran, inside the steps
        assert abs(part["kernel_us"] + part["other_us"] - part["step_us"]) < 0.2
        assert report["summary"][f"{label}_kernel_us"]["min"] == part["kernel_us"]
    assert report["samples"][0]["speed_probe"]["python_ms"] > 0
    cross = report["samples"][0]["cross_core_ns"]
    assert cross is None or cross > 0  # None with one usable CPU
    assert "cpu" in report["machine"]


def test_bad_arguments_exit_2_naming_the_value() -> None:
    bad = subprocess.run([sys.executable, str(SCRIPT), "--steps", "0"],
                         capture_output=True, text=True, timeout=600)
    assert bad.returncode == 2
    assert "--steps must be >= 1 (got 0)" in bad.stderr
    over = subprocess.run([sys.executable, str(SCRIPT), "--warm-points", "3990", "--steps",
                           "20"], capture_output=True, text=True, timeout=900)
    assert over.returncode == 2
    assert "--warm-points + --steps must be at most 4000 (got 4010)" in over.stderr
