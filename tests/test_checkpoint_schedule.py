"""When periodic checkpoints are taken: the robots' first ones staggered over an interval, and
each taken and booked at the loop's quiet moments, one per cycle (docs/fleet.md, *Checkpoints
one at a time*). Tested on :class:`Checkpoints` with stand-in robots and writes."""

from __future__ import annotations

from concurrent.futures import Future
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from roger_daemon.config import CheckpointConfig
from roger_daemon.daemon.service.checkpoints import Checkpoints

SECOND = 1_000_000_000


def _robots(n: int) -> dict[str, Any]:
    return {f"r{i}": SimpleNamespace(robot=f"r{i}", generation=0, updates=0, wal=None,
                                     decisions=None) for i in range(n)}


def _checkpoints(robots: dict[str, Any], **config: Any) -> Checkpoints:
    cfg = CheckpointConfig(dir=Path("unused"), **config)
    clock = SimpleNamespace(monotonic_ns=lambda: 0)
    ck = Checkpoints(cfg, robots, clock, snapshot=lambda *a: ({}, {}, {}),  # type: ignore[arg-type]
                     sync=True)
    ck.start(0)
    return ck


def test_the_robots_first_checkpoints_are_staggered_over_an_interval() -> None:
    robots = _robots(4)
    ck = _checkpoints(robots, every_updates=100, every_s=0)
    first = {}
    for generation in range(1, 101):
        for rt in robots.values():
            rt.generation = generation
        for rt in ck.due(0):
            first.setdefault(rt.robot, generation)
    assert first == {"r0": 100, "r1": 75, "r2": 50, "r3": 25}  # robot i: i/4 early
    _finished(ck, "r3")  # r3's first checkpoint, at generation 100, is written ...
    ck.collect()
    for rt in robots.values():
        rt.generation = 199
    assert "r3" not in [rt.robot for rt in ck.due(0)]  # ... its next one a whole interval on
    robots["r3"].generation = 200
    assert "r3" in [rt.robot for rt in ck.due(0)]
    by_time = _checkpoints(_robots(2), every_updates=0, every_s=10.0)
    for rt in by_time.robots.values():
        rt.generation = 1  # something learned
    assert [rt.robot for rt in by_time.due(5 * SECOND)] == ["r1"]
    assert [rt.robot for rt in by_time.due(10 * SECOND)] == ["r0", "r1"]


def _finished(ck: Checkpoints, robot: str) -> None:
    fut: Future[tuple[Path, Any]] = Future()
    # the fields of a CheckpointMeta that booking a finished checkpoint reads
    meta = SimpleNamespace(updates=0, model_digest="d", wal_seq=None, reason="periodic")
    fut.set_result((Path(f"{robot}.npz"), meta))
    ck.state[robot].in_flight = fut
    ck.state[robot].in_flight_gen = ck.robots[robot].generation


def test_checkpoints_are_taken_and_booked_one_per_quiet_cycle_or_all_once_overdue() -> None:
    robots = _robots(3)
    ck = _checkpoints(robots, every_updates=1, every_s=0)
    taken: list[str] = []
    ck.poll(SECOND, True, lambda rt: taken.append(rt.robot))  # nothing learned: none due
    for rt in robots.values():
        rt.generation = 1
    ck.poll(SECOND + 1, False, lambda rt: taken.append(rt.robot))  # not quiet: wait
    assert taken == []
    ck.poll(SECOND + 2, True, lambda rt: taken.append(rt.robot))
    assert taken == ["r0"]  # one per quiet cycle
    for robot in robots:
        _finished(ck, robot)
    ck.poll(SECOND + 3, True, lambda rt: taken.append(rt.robot))
    assert [st.in_flight is None for st in ck.state.values()] == [True, False, False]
    assert [st.written for st in ck.state.values()] == [1, 0, 0]
    taken.clear()
    ck.poll(3 * SECOND + 3, False, lambda rt: taken.append(rt.robot))  # a second without quiet
    assert taken == []  # r1 and r2 still had writes in flight, r0 nothing new ...
    assert [st.written for st in ck.state.values()] == [1, 1, 1]  # ... all booked at once
    for rt in robots.values():
        rt.generation = 2
    ck.poll(5 * SECOND, False, lambda rt: taken.append(rt.robot))
    assert taken == ["r0", "r1", "r2"]
