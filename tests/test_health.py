"""Status level (roger_daemon.daemon.health) and journald priorities (roger_daemon.console)."""

from __future__ import annotations

import logging
from typing import Any

import pytest

from roger_daemon.console import JournalFormatter, configure_logging
from roger_daemon.daemon.health import Health, is_stale, worst

S = 1_000_000_000


def status(**over: Any) -> dict[str, Any]:
    base: dict[str, Any] = {"ticks": 0, "dropped": 0, "latency_ms_p99": 1.0,
                            "info": {"inbox_overflow": 0, "missed_ticks": 0}}
    info = over.pop("info", {})
    base.update(over)
    base["info"] = {**base["info"], **info}
    return base


def test_ok_while_input_flows() -> None:
    h = Health()
    for i in range(10):
        assert h.assess(status(ticks=30 * i), i * S) == ("OK", "")


def test_drops_warn_then_error_and_recover() -> None:
    h = Health()
    h.assess(status(ticks=1), 0)
    assert h.assess(status(ticks=2, dropped=5), S) == ("WARN", "5 pairs dropped (queue full)")
    level, why = h.assess(status(ticks=3, dropped=5 + 168), 2 * S)
    assert level == "ERROR" and "168 pairs dropped" in why
    assert h.assess(status(ticks=4, dropped=173), 3 * S) == ("OK", "")  # judged by change


@pytest.mark.parametrize("over, level, text", [
    ({"info": {"inbox_overflow": 1285}}, "WARN", "inbox overflow 1285"),
    ({"info": {"missed_ticks": 3}}, "WARN", "missed ticks 3"),
    ({"latency_ms_p99": 150.0}, "WARN", "latency p99 150 ms"),
    ({"latency_ms_p99": 4500.0}, "ERROR", "latency p99 4500 ms"),
    ({"info": {"learn_errors": 1}}, "ERROR", "1 learn errors"),
    ({"info": {"checkpoint_errors": 2}}, "ERROR", "2 checkpoint errors"),
])
def test_thresholds(over: dict[str, Any], level: str, text: str) -> None:
    h = Health()
    h.assess(status(ticks=1), 0)
    got, why = h.assess(status(ticks=2, **over), S)
    assert got == level and text in why


def test_no_input_warns_after_five_seconds() -> None:
    h = Health()
    h.assess(status(ticks=7), 0)
    assert h.assess(status(ticks=7), 4 * S)[0] == "OK"
    assert h.assess(status(ticks=7), 6 * S) == ("WARN", "no perception for 6 s")
    assert h.assess(status(ticks=8), 7 * S)[0] == "OK"


def test_stale_and_worst() -> None:
    assert not is_stale(2.9, 1.0) and is_stale(3.1, 1.0) and is_stale(0.4, 10.0)
    assert worst(["OK", "WARN", "ERROR"]) == "ERROR" and worst([]) == "OK"


def test_journal_lines_carry_syslog_priorities(monkeypatch: pytest.MonkeyPatch) -> None:
    fmt = JournalFormatter("%(levelname)s %(name)s: %(message)s")

    def line(level: int, msg: str) -> str:
        return fmt.format(logging.LogRecord("roger.x", level, __file__, 1, msg, None, None))

    assert line(logging.WARNING, "dropped") == "<4>WARNING roger.x: dropped"
    assert line(logging.ERROR, "a\nb") == "<3>ERROR roger.x: a\n<3>b"
    assert line(logging.INFO, "ok").startswith("<6>") and line(logging.DEBUG, "d")[:3] == "<7>"
    monkeypatch.setenv("JOURNAL_STREAM", "8:1234")
    root = logging.getLogger()
    before = (list(root.handlers), root.level)
    try:
        configure_logging("warning")
        mine = [h for h in root.handlers if getattr(h, "_roger", False)]
        assert len(mine) == 1 and isinstance(mine[0].formatter, JournalFormatter)
        assert root.level == logging.WARNING
    finally:
        for h in mine:
            root.removeHandler(h)
        root.handlers[:] = before[0]
        root.setLevel(before[1])
