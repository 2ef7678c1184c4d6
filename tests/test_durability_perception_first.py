"""Acknowledged means durable for a *perception-first* sender (protocols/README.md section 7,
*Delivery and the lockstep client's timeout*; issue 55 point 6): perception(t), wait for
prediction(t), then action(t).

prediction(t) acknowledges pairs 0..t-1 only (action(t) was not sent yet), so when the daemon
dies the sender holds two unacknowledged ticks: t-1's pair may be lost with the daemon (its
action can die in transit or before the log's commit), and no daemon can make durable what
never reached it. The sender rule is therefore "re-send every tick after the newest
acknowledged pair" (with perception first: the tick before the unanswered one, then that
one), and the daemon recognises the re-sent pair that it had already learned.

Both kills are placed deterministically, with real daemon processes (kill -9), real Zenoh on
127.0.0.1 and real files: (a) right after prediction(k) and before action(k) leaves the
sender (pair k is lost with the daemon); (b) after a status has acknowledged pair k (pair k
is durable: its re-send must not be learned twice). Re-sending only the unanswered tick, the
rule section 7 gave before, loses pair k in (a): that is asserted too.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from daemon_sessions import synthetic_stream
from test_durability import Daemon, _answer

pytest.importorskip("roger_daemon.harness")

pytestmark = pytest.mark.integration


def _run(workdir: Path, n: int, kills: dict[int, str], *, resend_acknowledged: bool
         ) -> list[tuple[int, int]]:
    """``(tick, updates)`` of every prediction; ``kills``: tick -> "lost" or "durable"."""
    x, y, labels = synthetic_stream("sqrt", n)
    answers: list[tuple[int, int]] = []
    acked = 0  # pairs 0..acked-1 are acknowledged by an `updates` received
    d = Daemon(workdir)
    t = 0
    try:
        while t < n:
            d.client.perception(t, x[t])
            got = _answer(d, t)
            if got is None:  # the daemon died: a new one, and re-send
                d.close()
                d = Daemon(workdir)
                first = acked if resend_acknowledged else t
                for s in range(first, t):  # complete unacknowledged pairs, oldest first
                    d.client.perception(s, x[s])
                    if _answer(d, s) is None:
                        raise AssertionError("the new daemon died")
                    d.client.action(s, y[s], labels[s])
                continue
            answers.append((t, got))
            acked = max(acked, got)
            how = kills.pop(t, None)
            if how == "lost":
                d.proc.proc.kill()  # before action(t) leaves: pair t dies with the daemon
                d.proc.proc.wait()
            d.client.action(t, y[t], labels[t])
            if how == "durable":
                d.client.wait_status(lambda s, t=t: s.updates == t + 1)  # committed
                d.proc.proc.kill()
                d.proc.proc.wait()
            t += 1
    finally:
        d.close()
    return answers


def test_re_sending_every_unacknowledged_tick_loses_nothing(tmp_path: Path) -> None:
    n = 40
    answers = _run(tmp_path, n, {12: "lost", 25: "durable"}, resend_acknowledged=True)
    # prediction(t) counts pairs 0..t-1, every one exactly once: none lost, none twice
    final = {t: u for t, u in answers}
    assert [final[t] for t in range(n)] == list(range(n)), answers
    logs = "".join(p.read_text() for p in tmp_path.glob("daemon-*.log"))
    assert "received again (re-sent); not learned twice" in logs  # the durable kill's pair
    assert len(list(tmp_path.glob("daemon-*.log"))) == 3


def test_re_sending_only_the_unanswered_tick_loses_the_one_before(tmp_path: Path) -> None:
    """The rule section 7 stated before issue 55: pair k is gone once its daemon is."""
    n = 20
    answers = _run(tmp_path, n, {8: "lost"}, resend_acknowledged=False)
    final = {t: u for t, u in answers}
    assert final[8] == 8 and final[9] == 8  # pair 8 was never learned
    assert final[n - 1] == n - 2
