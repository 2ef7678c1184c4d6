"""The runnable examples in docs/examples/ run as pasted (the README points at them)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "docs" / "examples"


def run_example(name: str, timeout: float) -> str:
    out = subprocess.run([sys.executable, str(EXAMPLES / name)], capture_output=True,
                         text=True, timeout=timeout, cwd=EXAMPLES.parents[1])
    assert out.returncode == 0, out.stdout + out.stderr
    assert "Traceback" not in out.stderr
    return out.stdout


def test_the_learner_quickstart_learns_both_branches() -> None:
    out = run_example("learner_quickstart.py", 120)
    assert "learned 400 pairs" in out and "purity of the experts against the subtasks" in out
    purity = float(out.rsplit(":", 1)[1])
    assert purity >= 0.9  # the paper's settings on raw data give 0.77 here, the issue 0.60


@pytest.mark.integration
def test_your_own_robot_learns_and_predicts_through_a_real_daemon() -> None:
    """A 6-D -> 2-D profile, a real daemon on loopback, RobotClient on the robot's side."""
    out = run_example("your_robot.py", 240)
    assert "demonstrated 600 pairs" in out and "daemon exited with 0" in out
    median = float(out.split("over 60 new perceptions:")[1].split()[0])
    assert median < 0.1
