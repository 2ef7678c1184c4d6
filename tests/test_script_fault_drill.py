"""``scripts/fault_drill.py`` (docs/zenoh-notes.md §8, *The fault drill*): its windows and gaps,
and bad arguments exit 2 naming the value. The drill itself takes minutes (its figures are in
the docs)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from types import ModuleType

from script_testing import load_script

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "fault_drill.py"


def _module() -> ModuleType:
    return load_script("fault_drill", SCRIPT)


def test_only_gaps_within_a_window_of_the_router_up_count() -> None:
    max_gap = _module().max_gap
    times = [0.0, 0.1, 0.2, 5.0, 5.1, 9.0]
    assert max_gap(times, [(0.0, 0.2), (5.0, 5.1)]) == 0.1  # the outages are outside
    assert max_gap(times, [(0.0, 5.1)]) == 4.8  # a stall while up


def test_the_router_is_up_from_its_first_delivery_to_its_kill() -> None:
    up_windows = _module().up_windows
    events = [("start", 0.0), ("router_killed", 10.0), ("router_started", 15.0),
              ("end", 30.0)]
    arrivals = [1.0, 2.0, 9.9, 19.0, 29.0]

    def first_after(t: float) -> float | None:
        return next((a for a in arrivals if a > t), None)

    assert up_windows(events, first_after) == [(1.0, 10.0), (19.0, 30.0)]


def test_bad_arguments_exit_2_naming_the_value() -> None:
    out = subprocess.run([sys.executable, str(SCRIPT), "--kill-every", "3", "--outage-s", "5"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "--kill-every 3.0" in out.stderr
    assert "Traceback" not in out.stderr


def test_a_directory_it_did_not_make_is_refused(tmp_path: Path) -> None:
    (tmp_path / "notes.txt").write_text("mine")
    out = subprocess.run([sys.executable, str(SCRIPT), "--out", str(tmp_path)],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "is not empty" in out.stderr
    assert (tmp_path / "notes.txt").read_text() == "mine"
