"""The cross-core probe (``roger_daemon.core_probe``): two pinned threads hand a counter back
and forth; the machine record carries its reading at a run's start and end."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import threading

import numpy as np
import pytest

from roger_daemon.core_probe import hand_over, round_trip_ns
from roger_daemon.machine import describe, finish, machine_record

TWO_CPUS = len(os.sched_getaffinity(0)) >= 2


def _both_sides(trips: int) -> tuple[dict[bool, int], int]:
    counter = np.zeros(16, dtype=np.int64)
    made: dict[bool, int] = {}

    def side(starts: bool) -> None:
        made[starts] = hand_over(counter, trips, starts)

    threads = [threading.Thread(target=side, args=(s,)) for s in (False, True)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=600)
    return made, int(counter[0])


def test_the_two_sides_make_every_round_trip_in_turn() -> None:
    """Each round trip moves the counter by two, one step per side: 1,000 trips end at 2,000
    (the GIL is released, or the two sides could not take turns)."""
    made, final = _both_sides(1_000)
    assert made == {True: 1_000, False: 1_000}
    assert final == 2_000


def test_a_side_without_its_partner_gives_up_at_the_spin_limit() -> None:
    counter = np.zeros(16, dtype=np.int64)
    assert hand_over(counter, 5, False, 1_000) == 0  # waits for 1, which never comes
    assert counter[0] == 0
    assert hand_over(counter, 5, True, 1_000) == 0  # writes 1, waits for 2
    assert counter[0] == 1


@pytest.mark.skipif(not TWO_CPUS, reason="needs two usable CPUs")
def test_the_round_trip_between_two_cpus_is_a_positive_time() -> None:
    ns = round_trip_ns(trips=2_000, repeats=2)
    assert ns is not None and math.isfinite(ns) and ns > 0


def test_one_cpu_or_an_unusable_one_gives_no_reading() -> None:
    """The default pair is the first two CPUs the calling thread may use: a thread narrowed
    to one gets ``None``; so does a pair whose CPU cannot be pinned (both threads stop)."""
    got: list[float | None] = []

    def narrowed() -> None:
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
        got.append(round_trip_ns(trips=100, repeats=1))

    thread = threading.Thread(target=narrowed)
    thread.start()
    thread.join(timeout=600)
    assert got == [None]
    assert round_trip_ns(cpus=(min(os.sched_getaffinity(0)), 4095), trips=100, repeats=1) is None


@pytest.mark.skipif(not TWO_CPUS, reason="needs two usable CPUs")
def test_the_machine_record_carries_the_round_trip_at_start_and_end() -> None:
    record = finish(machine_record())
    start, end = record["cross_core_ns_start"], record["cross_core_ns_end"]
    assert start > 0 and end > 0
    assert f"cross-core round trip {start} -> {end} ns" in describe(record)
    bare = finish(machine_record(probe=False))
    assert "cross_core_ns_start" not in bare and "cross_core_ns_end" not in bare
    assert "cross-core" not in describe(bare)


def test_the_probe_alone_does_not_count_as_the_learner_having_run() -> None:
    """The probe compiles with numba, but ``kernels_cpu`` names the learner's kernels: a
    process that only probed has none."""
    script = ("import json\n"
              "from roger_daemon.machine import finish, machine_record\n"
              "print(json.dumps(sorted(finish(machine_record()))))\n")
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         timeout=600, check=True)
    keys = json.loads(out.stdout.strip().splitlines()[-1])
    assert "kernels_cpu" not in keys
    assert {"cross_core_ns_start", "cross_core_ns_end", "speed_probe"} <= set(keys)
