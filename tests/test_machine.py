"""The machine record every benchmark and the experiment report (``roger_daemon.machine``)."""

from __future__ import annotations

import json
import math
import os
import time
from pathlib import Path

import pytest

from roger_daemon.machine import (
    cpu_time_split,
    cpu_times,
    describe,
    finish,
    machine_record,
    speed_probe,
)


def test_the_record_says_what_ran_how_loaded_and_how_fast() -> None:
    record = machine_record()
    assert record["cpus"] >= 1 and record["cpu"]
    assert record["blas"] and all(b["threads"] >= 1 for b in record["blas"])
    probe = record["speed_probe"]
    assert set(probe) == {"python_ms", "memory_ms"}
    assert all(math.isfinite(v) and v > 0 for v in probe.values())
    assert "load_avg_1m_end" not in record
    time.sleep(0.1)  # a run: /proc/stat counts in clock ticks (10 ms)
    done = finish(record)
    assert done is record and done["load_avg_1m_end"] >= 0
    json.dumps(done)  # goes into the benchmarks' JSON as it is
    line = describe(done)
    assert f"load {done['load_avg_1m_start']} -> {done['load_avg_1m_end']}" in line
    assert f"Python {probe['python_ms']} ms" in line
    if cpu_times() is not None:  # Linux: how the CPU time went over the run, shares of 100
        split = done["cpu_time"]
        assert set(split) == {"busy_percent", "idle_percent", "steal_percent"}
        assert all(v >= 0 for v in split.values())
        assert sum(split.values()) == pytest.approx(100.0, abs=0.05)
        assert f"CPU stolen {split['steal_percent']} %" in line
    assert not any(key.startswith("_") for key in done)  # nothing private in the JSON


def test_the_probe_can_be_left_out_and_repeats_are_honoured() -> None:
    assert "speed_probe" not in machine_record(probe=False)
    assert "speed probe" not in describe(machine_record(probe=False))
    assert set(speed_probe(repeats=1)) == {"python_ms", "memory_ms"}


def test_cpu_times_read_the_machines_line_of_proc_stat(tmp_path: Path) -> None:
    stat = tmp_path / "stat"
    stat.write_text("cpu  5004759 1418392 875782 6578707 74988 0 69750 217969 0 0\n"
                    "cpu0 1 2 3 4 5 6 7 8 0 0\n", encoding="ascii")
    assert cpu_times(str(stat)) == [5004759, 1418392, 875782, 6578707, 74988, 0, 69750, 217969]
    stat.write_text("intr 1 2 3\n", encoding="ascii")
    assert cpu_times(str(stat)) is None
    assert cpu_times(str(tmp_path / "missing")) is None


def test_the_split_is_the_share_of_each_kind_of_time() -> None:
    start = [100, 10, 20, 1000, 5, 1, 2, 30]
    # 60 user + 0 nice + 15 system + 3 irq + 2 softirq busy, 100 idle + 10 iowait, 10 stolen
    end = [160, 10, 35, 1100, 15, 4, 4, 40]
    assert cpu_time_split(start, end) == {"busy_percent": 40.0, "idle_percent": 55.0,
                                          "steal_percent": 5.0}
    assert cpu_time_split(start, start) is None


def test_the_record_names_what_the_learners_kernels_were_compiled_for() -> None:
    """Absent where no kernel ran (numba not loaded); else LLVM's CPU name, the one target of
    roger_daemon/learner/engine/jit_target.py where it applies, and the user's with the host's
    features otherwise."""
    import subprocess
    import sys

    probe = ("import json, numpy as np\n"
             "from roger_daemon.machine import finish, machine_record\n"
             "before = finish(machine_record(probe=False))\n"
             "from roger_daemon.learner.engine import jit, jit_target\n"
             "jit.kernel_vector(np.zeros((2, 3)), np.zeros(3), 1.0, 2)\n"
             "after = finish(machine_record(probe=False))\n"
             "print(json.dumps([before.get('kernels_cpu'), after['kernels_cpu'],"
             " jit_target.pinned()]))\n")
    env = {k: v for k, v in os.environ.items()
           if k not in ("NUMBA_CPU_NAME", "NUMBA_CPU_FEATURES")}
    out = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True,
                         text=True, timeout=600, check=True)
    before, after, pinned = json.loads(out.stdout.strip().splitlines()[-1])
    assert before is None
    assert after == (pinned if pinned is not None else f"{after.split()[0]} (host features)")
    mine = subprocess.run([sys.executable, "-c", probe], env={**env, "NUMBA_CPU_NAME": "generic"},
                          capture_output=True, text=True, timeout=600, check=True)
    assert json.loads(mine.stdout.strip().splitlines()[-1])[1] == "generic"
    assert describe({"cpu": "x", "cpus": 2, "load_avg_1m_start": 0.5,
                     "kernels_cpu": "haswell"}).endswith(", kernels for haswell")
