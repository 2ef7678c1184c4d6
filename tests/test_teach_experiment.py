"""The scripted teacher (the HCC through the page's channel), ``roger experiment teach`` and
``roger bench teach``: the rule for taking over, and short real runs (slow)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from simulator.teach.scripted import disagrees


def test_the_teacher_takes_over_on_a_wrong_walk_or_motion_only() -> None:
    teacher = np.array([0.2, 0.0, 0.5, -0.2, 0.0, 0.0, 0.0, 0.3, 0.0])
    assert not disagrees(teacher, teacher)
    close = teacher.copy()
    close[0] += 0.05  # an eighth of the forward range
    close[3] += 0.5  # the head is not judged
    assert not disagrees(close, teacher)
    for i, v in ((0, -0.1), (2, -1.0)):
        wrong = teacher.copy()
        wrong[i] = v
        assert disagrees(wrong, teacher)
    kick = teacher.copy()
    kick[8] = 0.9
    assert disagrees(kick, teacher)


@pytest.mark.parametrize(("argv", "want"), [
    ([], (600.0, 0.0)),
    (["--demonstrate-duration", "18", "--correct-duration", "12"], (18.0, 12.0)),
    (["--demonstrate-minutes", "0.3", "--correct-minutes", "0.2"], (18.0, 12.0)),  # deprecated
])
def test_the_phases_are_durations_in_seconds(argv: list[str], want: tuple[float, float]
                                             ) -> None:
    """docs/cli.md: one word for a duration (issue 56); the minutes only as deprecated."""
    from roger_daemon.cli import COMMANDS, build_parser
    from simulator.teach.experiment import phase_durations

    args = build_parser(COMMANDS, "roger", "experiment").parse_args(
        ["experiment", "teach", *argv])
    phase_durations(args)
    assert (args.demonstrate_s, args.correct_s) == pytest.approx(want)


def test_a_phase_given_twice_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    from roger_daemon.cli import main

    assert main(["experiment", "teach", "--demonstrate-duration", "5",
                 "--demonstrate-minutes", "1"]) == 2
    err = capsys.readouterr().err
    assert "--demonstrate-duration S or the deprecated --demonstrate-minutes" in err
    assert "Traceback" not in err


def _roger(*args: str, timeout: float = 600) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "roger_daemon", *args], capture_output=True,
                          text=True, timeout=timeout)


@pytest.mark.slow
@pytest.mark.integration
def test_experiment_teach_demonstrates_corrects_and_evaluates(tmp_path: Path) -> None:
    out = tmp_path / "et"
    done = _roger("experiment", "teach", "--out", str(out), "--demonstrate-duration", "18",
                  "--correct-duration", "12", "--locations", "0,6", "--episode-duration", "15")
    assert done.returncode == 0, done.stderr[-3000:]
    r = json.loads((out / "results.json").read_text())
    assert r["teach_exit"] == 130 and r["trials"] == 2 and 0 <= r["goals"] <= 2
    assert [e["location"] for e in r["per_location"]] == [0, 6]
    assert r["teacher"]["demonstrated"] == 18 * 30
    # the daemon counted every correction the loop applied; the teacher's answer to the tick
    # on which the mode changed may not be applied
    assert r["corrections_daemon"] == r["page_counts"]["corrections"] > 0
    assert 0 <= r["teacher"]["corrected"] - r["corrections_daemon"] <= 1
    assert r["pairs_learned"] == r["pairs_teacher"] == r["page_counts"]["pairs_sent"]
    assert r["transitions"]["fit"] == "loaded" and not r["refused"]


@pytest.mark.slow
@pytest.mark.integration
def test_bench_teach_reports_its_figures() -> None:
    if not Path("/usr/bin/chromium").exists():
        pytest.skip("no /usr/bin/chromium")
    done = _roger("bench", "teach", "--json", "--presses", "8", "--gap", "0.2",
                  "--vision", "fast")
    r = json.loads(done.stdout.strip().splitlines()[-1])
    assert done.returncode in (0, 1) and r["teach_exit"] == 130
    assert r["commands_measured"] >= 8 and r["key_to_received_ms"]["p99"] is not None
    assert set(r["met"]) == set(r["targets"]) and r["page_hz"] > 0
