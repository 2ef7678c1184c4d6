"""When the status round runs: once due, after the answers, one robot at a time (docs/fleet.md,
*Status after the answers*, *Status one robot at a time*). The rule is tested on its own, a
:class:`StatusPublisher` with the parts it reads, and the round through a real service loop."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

from protocols import decode, keys
from roger_daemon.config import parse_config
from roger_daemon.daemon.main import build_robot
from roger_daemon.daemon.service import Service
from roger_daemon.daemon.service.status import StatusPublisher
from roger_daemon.testing import MemoryTransport

SECOND = 1_000_000_000
PERIOD = SECOND // 30


def _svc(*, realtime: bool, answering: bool = False, inbox: int = 0,
         next_tick: int = 0, delivering: bool = False) -> StatusPublisher:
    """A status publisher with only the parts its schedule reads; a round due at 10 s."""
    learners = SimpleNamespace(answering=lambda: answering,  # a learner_host.Learners
                               delivering=lambda: delivering)
    parts: Any = SimpleNamespace(learners=learners, inbox=[None] * inbox,
                                 schedule=SimpleNamespace(next_tick=next_tick,
                                                          period_ns=PERIOD))
    config: Any = SimpleNamespace(status_hz=1.0, clock="realtime" if realtime else "lockstep")
    pub = StatusPublisher(config, {}, parts=parts, timer_active=lambda: realtime,
                          commit=lambda rt: None, commit_all=lambda robots: None)
    pub.start(9 * SECOND)
    return pub


def test_not_before_it_is_due() -> None:
    svc = _svc(realtime=False)
    assert not svc.due(10 * SECOND - 1)
    assert svc.due(10 * SECOND)
    assert svc.deadline(10 * SECOND - 1) == 10 * SECOND


def test_lockstep_waits_for_the_answers_in_flight_and_the_inbox() -> None:
    now = 10 * SECOND + 5_000_000
    assert not _svc(realtime=False, answering=True).due(now)
    assert not _svc(realtime=False, inbox=3).due(now)
    assert _svc(realtime=False).due(now)
    held = _svc(realtime=False, answering=True)
    assert held.deadline(now) == 10 * SECOND + SECOND // 4


def test_held_at_most_a_quarter_of_its_period() -> None:
    svc = _svc(realtime=False, answering=True, inbox=5)
    assert not svc.due(10 * SECOND + SECOND // 4 - 1)
    assert svc.due(10 * SECOND + SECOND // 4)


def test_realtime_runs_in_the_first_quarter_after_a_tick() -> None:
    tick = 10 * SECOND + 2 * PERIOD  # the next tick; the last one was a period before
    last = tick - PERIOD
    svc = _svc(realtime=True, next_tick=tick)
    assert svc.due(last + 1)  # right after a tick
    assert svc.due(last + PERIOD // 4 - 1)
    assert not svc.due(last + PERIOD // 4 + 1)  # later: the next tick comes first
    assert not svc.due(tick - 1)


def test_quiet_moments_are_the_ones_status_waits_for() -> None:
    now = 10 * SECOND
    assert _svc(realtime=False).quiet_moment(now)
    assert not _svc(realtime=False, answering=True).quiet_moment(now)
    assert not _svc(realtime=False, inbox=1).quiet_moment(now)
    tick = now + PERIOD // 2
    assert not _svc(realtime=True, next_tick=tick).quiet_moment(now)  # half a period to go
    assert _svc(realtime=True, next_tick=now + PERIOD - 1).quiet_moment(now)  # just ticked
    # ... unless its predictions are still being delivered (the workers' delivery window)
    delivering = _svc(realtime=True, next_tick=now + PERIOD - 1, delivering=True)
    assert not delivering.quiet_moment(now)


def test_a_round_under_way_goes_on_at_quiet_moments_until_overdue() -> None:
    svc = _svc(realtime=False, answering=True)
    svc.round.start(10 * SECOND, [SimpleNamespace()], {})
    svc.next_ns = 11 * SECOND  # the round started: the next one is due in a second
    now = 10 * SECOND + 1
    assert not svc.due(now)  # an answer is in flight
    assert svc.deadline(now) == 10 * SECOND + SECOND // 4
    assert svc.due(10 * SECOND + SECOND // 4)  # overdue
    quiet = _svc(realtime=False)
    quiet.round.start(10 * SECOND, [SimpleNamespace()], {})
    quiet.next_ns = 11 * SECOND
    assert quiet.due(now) and quiet.deadline(now) == now  # the next one now


class _Clock:
    def __init__(self) -> None:
        self.mono = SECOND

    def monotonic_ns(self) -> int:
        return self.mono

    def time_ns(self) -> int:
        return 1_700_000_000 * SECOND + self.mono


def test_a_status_round_publishes_one_robot_per_cycle_until_overdue(tmp_path: Path) -> None:
    robots = ["r0", "r1", "r2"]
    cfg = parse_config({
        "daemon": {"clock": "lockstep"}, "robots": [{"id": r} for r in robots],
        "checkpoint": {"dir": str(tmp_path / "ckpt"), "every_updates": 0, "every_s": 0},
        "recording": {"enabled": False}})
    clock = _Clock()
    transport = MemoryTransport(now_ns=clock.monotonic_ns)
    built = {r.id: build_robot(cfg, r, fresh=True)[0] for r in cfg.robots}
    svc = Service(cfg, transport, built, clock=clock, sync_checkpoints=True)
    svc.start()

    def published() -> list[str]:
        out = []
        for key, data in transport.take("status"):
            robot, _ = keys.parse(key)
            out.append(decode("status", data, dims=built[robot].dims, robot=robot).robot)
        return out

    clock.mono += SECOND  # the first round is due; every cycle is a quiet moment here
    got = []
    for _ in range(3):
        svc.step(0)
        got.append(published())
    assert got == [["r0"], ["r1"], ["r2"]]
    svc.step(0)
    assert published() == []  # the round is over; the next is due a second after this one
    clock.mono += SECOND
    svc.step(0)
    assert published() == ["r0"]
    clock.mono += SECOND // 4  # overdue: the rest of the round at once
    svc.step(0)
    assert published() == ["r1", "r2"]
    svc.shutdown()
