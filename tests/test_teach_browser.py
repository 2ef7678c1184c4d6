"""``roger teach`` in a real browser: headless Chromium (Debian's) through Playwright.

One real session (``roger teach`` as a subprocess: the simulator's loop, a ``roger daemon``
subprocess, the page served with websockets) driven as a person would: keys held on the page
move the simulated robot and the daemon learns those pairs; autonomous mode makes the robot
act on what it learned; in correct mode a held key replaces the robot's command and those
pairs are learned, counted as corrections and tagged in the session's MCAP log and in ``roger
log export``; malformed, out-of-range and flooding input from the page is refused and counted
while the session goes on; Ctrl-C exits 130 and leaves nothing running.

``make test`` installs Chromium (``apt-get install chromium``) where it is missing; without it
the test is skipped, except under CI (``CI=true``), where it fails.
"""

from __future__ import annotations

import math
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from cli_testing import in_process

from tests.process_testing import processes_naming

pytestmark = pytest.mark.integration

CHROMIUM = Path(os.environ.get("ROGER_CHROMIUM", "/usr/bin/chromium"))
try:
    import playwright.sync_api  # noqa: F401
    _MISSING = "" if CHROMIUM.exists() else f"no {CHROMIUM}"
except ImportError:
    _MISSING = "no playwright"
if _MISSING:
    if os.environ.get("CI") == "true":
        raise RuntimeError(f"{_MISSING}: `make test` installs Chromium and Playwright")
    pytest.skip(f"{_MISSING} (make test installs it)", allow_module_level=True)


def _start(out: Path) -> tuple[subprocess.Popen[str], str]:
    env = {**os.environ, "ROGER_LOG_LEVEL": "INFO", "RUST_LOG": "error",
           "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "roger_daemon", "teach", "--http", "127.0.0.1:0", "--out",
         str(out), "--vision", "fast", "--episode-duration", "300", "--seed", "3"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    assert proc.stdout is not None
    end = time.monotonic() + 150
    lines = []
    while time.monotonic() < end:
        line = proc.stdout.readline()
        if not line:
            break
        lines.append(line)
        m = re.search(r"the page is at (http://\S+/)", line)
        if m:
            return proc, m.group(1)
    proc.kill()
    raise AssertionError("roger teach did not print its address:\n" + "".join(lines))


@pytest.fixture
def teach(tmp_path: Path) -> Iterator[tuple[subprocess.Popen[str], str, Path]]:
    proc, url = _start(tmp_path / "teach")
    try:
        yield proc, url, tmp_path / "teach" / "session-0"
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(30)


def _state(page: Any) -> dict[str, Any]:
    st: dict[str, Any] = page.evaluate("window.teach.state")
    return st


def _wait(page: Any, predicate: str, timeout_s: float = 30.0) -> None:
    page.wait_for_function(predicate, timeout=timeout_s * 1000)


def _hold(page: Any, key: str, seconds: float) -> None:
    page.keyboard.down(key)
    time.sleep(seconds)
    page.keyboard.up(key)


def _pose(page: Any) -> tuple[float, float, float]:
    t = _state(page)["truth"]
    return t["robot_x"], t["robot_y"], t["robot_yaw"]


def test_teach_in_a_browser(teach: tuple[subprocess.Popen[str], str, Path],
                            capsys: pytest.CaptureFixture[str],
                            monkeypatch: pytest.MonkeyPatch) -> None:
    from playwright.sync_api import sync_playwright

    proc, url, session = teach
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=str(CHROMIUM), headless=True,
                                     args=["--no-sandbox"])
        page = browser.new_page()
        page.goto(url)
        _wait(page, "window.teach.config && window.teach.stats.states > 5")
        assert page.locator("#keymap tbody tr").count() == 12  # the key map is shown
        assert "learned transitions" in page.locator("#autonomy").inner_text()

        # demonstrate: walking forward moves the robot, the daemon learns those pairs
        x0, y0, yaw0 = _pose(page)
        _hold(page, "KeyW", 1.5)
        _wait(page, "window.teach.state.daemon && window.teach.state.daemon.pairs_teacher > 30")
        x1, y1, _ = _pose(page)
        forward = (x1 - x0) * math.cos(yaw0) + (y1 - y0) * math.sin(yaw0)
        assert forward > 0.1, (x0, y0, x1, y1)
        st = _state(page)
        assert st["mode"] == "demonstrate" and st["daemon"]["updates"] > 30

        # autonomous: the robot acts on what it learned
        page.click("#modes button[data-mode=autonomous]")
        _wait(page, "window.teach.state.mode === 'autonomous' && "
                    "window.teach.state.fsm.how === 'learned transitions'")  # loaded
        a0 = _pose(page)
        time.sleep(1.5)
        st = _state(page)
        a1 = _pose(page)
        assert st["source"] == "robot" and st["fsm"]["how"] == "learned transitions"
        assert st["fsm"]["fit"] == "loaded" and st["counts"]["ticks_robot"] > 10
        # what executes is the robot's own command, the chosen expert's mean (whether it
        # walks depends on what was learned at this perception: not asserted)
        assert st["command"] == st["robot_y"], (a0, a1)

        # correct: a held key replaces the robot's command; its pairs are corrections
        page.click("#modes button[data-mode=correct]")
        _wait(page, "window.teach.state.mode === 'correct'")
        yaw_before = _pose(page)[2]
        _hold(page, "KeyE", 1.0)
        _wait(page, "window.teach.state.daemon.corrections > 10")
        turned = math.remainder(_pose(page)[2] - yaw_before, 2 * math.pi)
        assert turned < -0.2, turned  # KeyE turns right

        # bad input from the page: refused, counted, the session goes on
        tick = _state(page)["tick"]
        page.evaluate("""() => {
            const ws = window.teach.ws;
            ws.send("not json"); ws.send("[1, 2]"); ws.send(JSON.stringify({type: "fly"}));
            ws.send(JSON.stringify({type: "command", y: [9, 0, 0, 0, 0, 0, 0, 0, 0]}));
            ws.send(JSON.stringify({type: "command", y: [0, 0]}));
            for (let i = 0; i < 3000; i++) ws.send(JSON.stringify({type: "checkpoint!"}));
        }""")
        _wait(page, "window.teach.state.refused.flood > 0 && "
                    "window.teach.state.refused.not_json === 1")
        refused = _state(page)["refused"]
        assert refused["out_of_range"] == 1 and refused["bad_field"] == 1
        assert refused["not_an_object"] == 1 and refused["unknown_type"] >= 1
        _wait(page, f"window.teach.state.tick > {tick + 30}")  # still stepping
        page.click("#modes button[data-mode=demonstrate]")
        _wait(page, "window.teach.state.mode === 'demonstrate'")

        # the buttons: a take, a checkpoint, a reset at a chosen location, the ball placed
        page.click("#record")
        _wait(page, "window.teach.state.recording === true")
        page.click("#checkpoint")
        _wait(page, "document.getElementById('answer').textContent.startsWith('checkpoint ')")
        page.click("#record")
        _wait(page, "window.teach.state.recording === false")
        episode = _state(page)["episode"]
        page.select_option("#location", "6")
        page.click("#reset")
        _wait(page, f"window.teach.state.episode > {episode} && window.teach.state.location === 6")
        page.click("#field", position={"x": 300, "y": 100})  # ahead, to the robot's left
        _wait(page, f"window.teach.state.episode > {episode + 1}")
        ball = _state(page)["truth"]
        assert ball["ball_x"] > 0.5 and ball["ball_y"] > 0.3, ball
        browser.close()

    proc.send_signal(signal.SIGINT)
    assert proc.wait(60) == 130
    assert not processes_naming(str(session))  # the daemon and the take's recorder
    assert list((session / "takes").rglob("*.mcap"))
    _check_log(session, capsys, monkeypatch)


def _check_log(session: Path, capsys: pytest.CaptureFixture[str],
               monkeypatch: pytest.MonkeyPatch) -> None:
    """The session's MCAP log tags every learned pair's source; the corrections are there;
    ``roger log export`` keeps the source."""
    import pyarrow.parquet as pq

    from protocols import Action, decode, keys
    from roger_daemon.recording.mcapio import LogReader

    logs = sorted((session / "recordings").rglob("*.mcap"))
    assert len(logs) == 1
    actions = [decode("action", lm.message.data) for lm in LogReader(logs[0]).messages()
               if lm.topic == keys.action("aibo")]
    assert actions and all(isinstance(a, Action) and a.source == "teacher" for a in actions)
    corrections = sum(bool(a.correction) for a in actions)  # type: ignore[attr-defined]
    assert corrections > 10
    out = session / "export"
    with in_process(capsys, monkeypatch) as run:  # tests/cli_testing.py
        done = run("log", "export", str(logs[0]), "--format", "parquet", "--out", str(out))
    assert done.returncode == 0, done.stderr
    table = pq.read_table(next(out.glob("*.parquet")))
    sources = set(table.column("source").to_pylist())
    assert sources == {"teacher"}
