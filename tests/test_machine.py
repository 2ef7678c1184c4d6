"""The machine record every benchmark and the experiment report (``roger_daemon.machine``)."""

from __future__ import annotations

import json
import math

from roger_daemon.machine import describe, finish, machine_record, speed_probe


def test_the_record_says_what_ran_how_loaded_and_how_fast() -> None:
    record = machine_record()
    assert record["cpus"] >= 1 and record["cpu"]
    assert record["blas"] and all(b["threads"] >= 1 for b in record["blas"])
    probe = record["speed_probe"]
    assert set(probe) == {"python_ms", "memory_ms"}
    assert all(math.isfinite(v) and v > 0 for v in probe.values())
    assert "load_avg_1m_end" not in record
    done = finish(record)
    assert done is record and done["load_avg_1m_end"] >= 0
    json.dumps(done)  # goes into the benchmarks' JSON as it is
    line = describe(done)
    assert f"load {done['load_avg_1m_start']} -> {done['load_avg_1m_end']}" in line
    assert f"Python {probe['python_ms']} ms" in line


def test_the_probe_can_be_left_out_and_repeats_are_honoured() -> None:
    assert "speed_probe" not in machine_record(probe=False)
    assert "speed probe" not in describe(machine_record(probe=False))
    assert set(speed_probe(repeats=1)) == {"python_ms", "memory_ms"}
