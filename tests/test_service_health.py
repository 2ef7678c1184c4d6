"""The daemon's side of the operator tools: control confirmation and the status level."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest
from test_daemon_service import Harness, make_config

from protocols import Control, Status, decode, encode


def _statuses(h: Harness) -> list[Status]:
    out = []
    for _, data in h.transport.take("status"):
        st = decode("status", data, robot="aibo")
        assert isinstance(st, Status)
        out.append(st)
    return out


def test_a_control_is_confirmed_at_once_by_a_status_carrying_its_stamp(tmp_path: Path) -> None:
    h = Harness(make_config(tmp_path))
    h.transport.take("status")
    h.send("control", encode(Control("aibo", 0, 0.0, op="mode", mode="predict",
                                     stamp_ns=123_456_789)))
    h.service.step(0)  # no time passes: only the confirmation can be published
    (ack,) = _statuses(h)
    assert ack.mode == "predict"
    assert ack.info["control_stamp_ns"] == 123_456_789
    assert ack.info["control_op"] == "mode" and ack.info["controls"] == 1
    h.send("control", encode(Control("aibo", 0, 0.0, op="reset", stamp_ns=5)))
    h.service.step(0)
    (ack,) = _statuses(h)
    assert (ack.info["control_stamp_ns"], ack.info["controls"]) == (5, 2)


def test_periodic_status_carries_level_and_reasons(tmp_path: Path) -> None:
    h = Harness(make_config(tmp_path))
    h.pair(0)
    h.settle()
    st = h.status()
    assert st.info["level"] == "OK" and st.info["level_reasons"] == ""
    for _ in range(6):  # no perception for 6 s
        st = h.status()
    assert st.info["level"] == "WARN" and "no perception for" in st.info["level_reasons"]


def test_a_change_of_level_is_logged(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    h = Harness(make_config(tmp_path))
    h.pair(0)
    h.settle()
    with caplog.at_level(logging.INFO, logger="roger_daemon.daemon.service"):
        for _ in range(7):
            h.status()
    warned = [r for r in caplog.records if "status WARN" in r.getMessage()]
    assert len(warned) == 1 and warned[0].levelno == logging.WARNING
    assert "no perception for" in warned[0].getMessage()
