"""When the status round runs: once due, after the answers (docs/fleet.md, *Status after the
answers*). The rule is tested on its own, with the loop's fields it reads."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

from roger_daemon.daemon.service.status import quiet_moment, status_deadline, status_due

SECOND = 1_000_000_000
PERIOD = SECOND // 30


def _svc(*, realtime: bool, answering: bool = False, inbox: int = 0,
         next_tick: int = 0) -> Any:
    learners = SimpleNamespace(answering=lambda: answering)
    return SimpleNamespace(
        _next_status=10 * SECOND, _status_period_ns=SECOND, _realtime=realtime,
        _timer_active=lambda: realtime, learners=learners, inbox=[None] * inbox,
        schedule=SimpleNamespace(next_tick=next_tick, period_ns=PERIOD))


def test_not_before_it_is_due() -> None:
    svc = _svc(realtime=False)
    assert not status_due(svc, 10 * SECOND - 1)
    assert status_due(svc, 10 * SECOND)
    assert status_deadline(svc, 10 * SECOND - 1) == 10 * SECOND


def test_lockstep_waits_for_the_answers_in_flight_and_the_inbox() -> None:
    now = 10 * SECOND + 5_000_000
    assert not status_due(_svc(realtime=False, answering=True), now)
    assert not status_due(_svc(realtime=False, inbox=3), now)
    assert status_due(_svc(realtime=False), now)
    held = _svc(realtime=False, answering=True)
    assert status_deadline(held, now) == 10 * SECOND + SECOND // 4


def test_held_at_most_a_quarter_of_its_period() -> None:
    svc = _svc(realtime=False, answering=True, inbox=5)
    assert not status_due(svc, 10 * SECOND + SECOND // 4 - 1)
    assert status_due(svc, 10 * SECOND + SECOND // 4)


def test_realtime_runs_in_the_first_quarter_after_a_tick() -> None:
    tick = 10 * SECOND + 2 * PERIOD  # the next tick; the last one was a period before
    last = tick - PERIOD
    svc = _svc(realtime=True, next_tick=tick)
    assert status_due(svc, last + 1)  # right after a tick
    assert status_due(svc, last + PERIOD // 4 - 1)
    assert not status_due(svc, last + PERIOD // 4 + 1)  # later: the next tick comes first
    assert not status_due(svc, tick - 1)


def test_quiet_moments_are_the_ones_status_waits_for() -> None:
    now = 10 * SECOND
    assert quiet_moment(_svc(realtime=False), now)
    assert not quiet_moment(_svc(realtime=False, answering=True), now)
    assert not quiet_moment(_svc(realtime=False, inbox=1), now)
    tick = now + PERIOD // 2
    assert not quiet_moment(_svc(realtime=True, next_tick=tick), now)  # half a period to go
    assert quiet_moment(_svc(realtime=True, next_tick=now + PERIOD - 1), now)  # just ticked
